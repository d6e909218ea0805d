"""Deprecated alias of :mod:`nurbscan.peers.graycode` (the peer scanners moved to
:mod:`nurbscan.peers`, issue 37). Every attribute is forwarded with a DeprecationWarning."""

from __future__ import annotations

import warnings

from .peers import graycode as _graycode


def __getattr__(name: str):
    warnings.warn("nurbscan.graycode is deprecated: use nurbscan.peers.graycode",
                  DeprecationWarning, stacklevel=2)
    return getattr(_graycode, name)


def __dir__() -> list[str]:
    return dir(_graycode)
