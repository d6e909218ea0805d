// nurbscan report viewer: draws the embedded GLB meshes with three.js (vendored, inlined).
// Part of nurbscan (BSD-3-Clause). Reads <script type="application/octet-stream" id="glb-*">.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

function b64ToBuffer(text) {
  const s = atob(text.trim());
  const out = new Uint8Array(s.length);
  for (let i = 0; i < s.length; i++) out[i] = s.charCodeAt(i);
  return out.buffer;
}

const CTORS = { 5120: Int8Array, 5121: Uint8Array, 5122: Int16Array, 5123: Uint16Array,
  5125: Uint32Array, 5126: Float32Array };
const COMPS = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4 };

// A minimal GLB 2.0 reader for the meshes nurbscan writes (one buffer, indexed triangles).
function parseGlb(buf) {
  const dv = new DataView(buf);
  if (dv.getUint32(0, true) !== 0x46546c67) throw new Error("not a GLB file");
  const jlen = dv.getUint32(12, true);
  const json = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 20, jlen)));
  const blen = dv.getUint32(20 + jlen, true);
  const bin = buf.slice(28 + jlen, 28 + jlen + blen);
  const accessor = (i) => {
    const a = json.accessors[i];
    const bv = json.bufferViews[a.bufferView];
    const n = COMPS[a.type];
    const arr = new CTORS[a.componentType](bin, (bv.byteOffset || 0) + (a.byteOffset || 0),
      a.count * n);
    return new THREE.BufferAttribute(arr, n, !!a.normalized);
  };
  const group = new THREE.Group();
  for (const node of json.nodes || []) {
    if (node.mesh === undefined) continue;
    for (const prim of json.meshes[node.mesh].primitives) {
      const g = new THREE.BufferGeometry();
      g.setAttribute("position", accessor(prim.attributes.POSITION));
      if (prim.attributes.NORMAL !== undefined) g.setAttribute("normal", accessor(prim.attributes.NORMAL));
      if (prim.attributes.COLOR_0 !== undefined) g.setAttribute("color", accessor(prim.attributes.COLOR_0));
      if (prim.indices !== undefined) g.setIndex(accessor(prim.indices));
      if (prim.attributes.NORMAL === undefined) g.computeVertexNormals();
      const mat = new THREE.MeshStandardMaterial({ vertexColors: prim.attributes.COLOR_0 !== undefined,
        side: THREE.DoubleSide, roughness: 0.8, metalness: 0.0 });
      const mesh = new THREE.Mesh(g, mat);
      if (node.matrix) mesh.applyMatrix4(new THREE.Matrix4().fromArray(node.matrix));
      group.add(mesh);
    }
  }
  return group;
}

const holder = document.getElementById("viewer");
const status = document.getElementById("viewer-status");
try {
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(holder.clientWidth, holder.clientHeight);
  renderer.setClearColor(0x1d2229);
  holder.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.add(new THREE.HemisphereLight(0xffffff, 0x444450, 1.6));
  const sun = new THREE.DirectionalLight(0xffffff, 1.6);
  scene.add(sun);
  const models = {};
  for (const el of document.querySelectorAll("script[id^='glb-']")) {
    const g = parseGlb(b64ToBuffer(el.textContent));
    g.visible = Object.keys(models).length === 0;
    models[el.id.slice(4)] = g;
    scene.add(g);
  }
  const first = Object.values(models)[0];
  const box = new THREE.Box3().setFromObject(first);
  const sphere = box.getBoundingSphere(new THREE.Sphere());
  const camera = new THREE.PerspectiveCamera(35, holder.clientWidth / holder.clientHeight,
    sphere.radius / 100, sphere.radius * 100);
  // object frame: z up; look from the front-right, slightly above
  camera.up.set(0, 0, 1);
  const dir = new THREE.Vector3(1.0, -0.6, 0.45).normalize();
  camera.position.copy(sphere.center).addScaledVector(dir, sphere.radius * 3.2);
  camera.lookAt(sphere.center);
  const controls = new OrbitControls(camera, renderer.domElement);
  controls.target.copy(sphere.center);
  controls.update();
  const draw = () => {
    sun.position.copy(camera.position);
    renderer.render(scene, camera);
  };
  controls.addEventListener("change", draw);
  for (const b of document.querySelectorAll("button[data-show]")) {
    b.addEventListener("click", () => {
      for (const [k, g] of Object.entries(models)) g.visible = k === b.dataset.show;
      for (const o of document.querySelectorAll("button[data-show]")) o.classList.toggle("on", o === b);
      document.getElementById("legend").style.display = b.dataset.show === "error" ? "block" : "none";
      draw();
    });
  }
  window.addEventListener("resize", () => {
    renderer.setSize(holder.clientWidth, holder.clientHeight);
    camera.aspect = holder.clientWidth / holder.clientHeight;
    camera.updateProjectionMatrix();
    draw();
  });
  const start = document.querySelector(`button[data-show="${location.hash.slice(1)}"]`);
  if (start) start.click();
  draw();
  status.textContent = "drag to rotate, wheel to zoom, right-drag to pan";
  document.body.dataset.viewer = "ok";
} catch (err) {
  status.textContent = "3-D view unavailable: " + err;
  document.body.dataset.viewer = "error";
}
