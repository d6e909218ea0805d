"""Measuring a reconstruction against the simulator's truth (the paper's Table I)."""

from .table import PAPER, ROWS, entity_errors, evaluate_model, format_table

__all__ = ["PAPER", "ROWS", "entity_errors", "evaluate_model", "format_table"]
