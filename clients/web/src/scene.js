// The 3D scene: scene.glb in three.js, the selected defect highlighted, the camera flown to it.
import * as THREE from "three";
import { GLTFLoader } from "three/examples/jsm/loaders/GLTFLoader.js";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";

const HIGHLIGHT = new THREE.MeshStandardMaterial({
  color: 0xffcc00, emissive: 0x664400, roughness: 0.5,
});
const FLIGHT_MS = 600;
const LABEL_M = 0.024; // a panel label's width in the scene, metres

// A panel's id drawn where its top's centre is: the numbers a seam's "panels a → b" and
// its step's sign refer to.
function panelLabel(id, centroidMm) {
  const canvas = document.createElement("canvas");
  canvas.width = 128;
  canvas.height = 64;
  const context = canvas.getContext("2d");
  context.fillStyle = "rgba(15, 23, 34, 0.75)";
  context.fillRect(0, 0, 128, 64);
  context.fillStyle = "#59d9ff";
  context.font = "bold 40px sans-serif";
  context.textAlign = "center";
  context.textBaseline = "middle";
  context.fillText(`P${id}`, 64, 34);
  const material = new THREE.SpriteMaterial({ map: new THREE.CanvasTexture(canvas), depthTest: false });
  const label = new THREE.Sprite(material);
  const [x, y, z] = centroidMm;
  label.position.set(x / 1000, z / 1000, -y / 1000); // base frame (mm, +Z up) → glTF (m, +Y up)
  label.scale.set(LABEL_M, LABEL_M / 2, 1);
  label.name = `label-panel-${id}`;
  label.userData.panelLabel = id;
  return label;
}

export class SceneView {
  constructor(canvas, onPick) {
    this.canvas = canvas;
    this.onPick = onPick;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: false });
    this.renderer.setPixelRatio(Math.min(devicePixelRatio, 2));
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0x0f1722);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x445566, 2.0));
    const sun = new THREE.DirectionalLight(0xffffff, 1.5);
    sun.position.set(1, 2, 1);
    this.scene.add(sun);
    this.camera = new THREE.PerspectiveCamera(45, 1, 0.001, 100);
    this.camera.position.set(0, 1, 2);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.enableDamping = true;
    // Frames are drawn only when something changed: an idle render loop would keep a
    // software-rendered (SwiftShader) browser's cores busy while the scene downloads.
    this.controls.addEventListener("change", () => this.invalidate());
    this.dirty = true;
    this.markers = new Map();
    this.selected = null;
    this.flight = null;
    this.root = null;
    this.raycaster = new THREE.Raycaster();
    canvas.addEventListener("click", (event) => this.pick(event));
    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
    this.renderer.setAnimationLoop((time) => this.frame(time));
  }

  resize() {
    const { clientWidth: width, clientHeight: height } = this.canvas;
    if (!width || !height) return;
    this.renderer.setSize(width, height, false);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    this.invalidate();
  }

  invalidate() {
    this.dirty = true;
  }

  // Shows a GLB in place of the last one. `frame`: point the camera at the whole scene (not
  // for a more detailed copy of the scene on show); `mark`: a performance mark set when it is
  // first drawn. Nothing changes when `isCurrent()` turns false while parsing.
  async load(arrayBuffer, { frame, mark, isCurrent = () => true }) {
    const gltf = await new GLTFLoader().parseAsync(arrayBuffer, "");
    if (!isCurrent()) return null;
    if (this.root) this.scene.remove(this.root);
    this.root = gltf.scene;
    this.scene.add(this.root);
    this.markers.clear();
    let points = 0;
    const labels = [];
    this.root.traverse((node) => {
      if (node.userData?.panel !== undefined && node.userData.centroid_mm) {
        labels.push(panelLabel(node.userData.panel, node.userData.centroid_mm));
      }
      const id = node.userData?.defect_id;
      if (id !== undefined && node.isMesh) this.markers.set(id, { node, material: node.material, scale: node.scale.clone() });
      if (node.isPoints) {
        node.material.size = 2.0;
        node.material.sizeAttenuation = false;
        points += node.geometry.attributes.position.count;
      }
    });
    for (const label of labels) this.root.add(label);
    if (frame) this.frameAll();
    if (this.selected !== null) this.select(this.selected, false);
    this.pendingMark = mark;
    this.invalidate();
    return { markers: this.markers.size, points, panels: labels.length };
  }

  frameAll() {
    const box = new THREE.Box3().setFromObject(this.root);
    const size = box.getSize(new THREE.Vector3()).length() || 1;
    const centre = box.getCenter(new THREE.Vector3());
    this.controls.target.copy(centre);
    this.camera.position.copy(centre).add(new THREE.Vector3(0, size * 0.5, size * 0.9));
    this.camera.near = size / 1000;
    this.camera.far = size * 20;
    this.camera.updateProjectionMatrix();
  }

  select(defectId, fly = true) {
    const previous = this.markers.get(this.selected);
    if (previous) {
      previous.node.material = previous.material;
      previous.node.scale.copy(previous.scale);
    }
    this.selected = defectId;
    this.invalidate();
    const marker = this.markers.get(defectId);
    if (!marker) return;
    marker.node.material = HIGHLIGHT;
    marker.node.scale.copy(marker.scale).multiplyScalar(1.4);
    if (fly) this.flyTo(marker.node);
  }

  flyTo(node) {
    const target = node.getWorldPosition(new THREE.Vector3());
    const [nx, ny, nz] = node.userData.normal || [0, 0, 1];
    const normal = new THREE.Vector3(nx, nz, -ny).normalize(); // base frame → glTF (+Y up)
    const distance = Math.max(0.25, node.scale.x * 8);
    const position = target.clone().add(normal.multiplyScalar(distance)).add(new THREE.Vector3(0, distance * 0.3, 0));
    this.flight = {
      start: performance.now(),
      fromTarget: this.controls.target.clone(), toTarget: target,
      fromPosition: this.camera.position.clone(), toPosition: position,
    };
  }

  pick(event) {
    const rect = this.canvas.getBoundingClientRect();
    const pointer = new THREE.Vector2(
      ((event.clientX - rect.left) / rect.width) * 2 - 1,
      -((event.clientY - rect.top) / rect.height) * 2 + 1,
    );
    this.raycaster.setFromCamera(pointer, this.camera);
    const nodes = [...this.markers.values()].map((m) => m.node);
    const hit = this.raycaster.intersectObjects(nodes, false)[0];
    if (hit) this.onPick(hit.object.userData.defect_id);
  }

  frame(time) {
    if (this.flight) {
      const t = Math.min(1, (time - this.flight.start) / FLIGHT_MS);
      const ease = t * t * (3 - 2 * t);
      this.controls.target.lerpVectors(this.flight.fromTarget, this.flight.toTarget, ease);
      this.camera.position.lerpVectors(this.flight.fromPosition, this.flight.toPosition, ease);
      if (t >= 1) this.flight = null;
      this.dirty = true;
    }
    this.controls.update(); // while damping, it fires "change"
    if (!this.dirty) return;
    this.dirty = false;
    this.renderer.render(this.scene, this.camera);
    if (this.pendingMark && this.root) {
      performance.mark(this.pendingMark);
      this.pendingMark = null;
      this.canvas.dataset.drawn = "true";
    }
  }
}
