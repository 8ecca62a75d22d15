// The 3D scene: scene.glb in three.js, the selected defect highlighted, the camera flown to
// it, base-frame axes and a scale bar.
import * as THREE from "three";
import { GLTFLoader } from "three/examples/jsm/loaders/GLTFLoader.js";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
import { Line2 } from "three/examples/jsm/lines/Line2.js";
import { LineGeometry } from "three/examples/jsm/lines/LineGeometry.js";
import { LineMaterial } from "three/examples/jsm/lines/LineMaterial.js";

// Markers are rings drawn over everything (no depth test): they circle what they mark and a
// panel never hides them. The selection's colour is no type's nor line's (main.js's legend).
export const SELECTED = 0x1de9b6;
const HIGHLIGHT = new THREE.MeshBasicMaterial({ color: SELECTED, side: THREE.DoubleSide, depthTest: false });
const SEAM_PX = 5; // the selected seam's width on screen (a plain WebGL line is one pixel)
const SEAM_HIGHLIGHT = new LineMaterial({ color: SELECTED, linewidth: SEAM_PX, depthTest: false });
const FLIGHT_MS = 600;
const LABEL_M = 0.024; // a panel label's width in the scene, metres
const PICK_SLACK_PX = 8; // a click this close to a ring picks it
const NEAREST_VIEW_M = 0.03; // the camera comes no closer than 30 mm when flying to a defect
const SCALE_BAR_PX = 120; // the scale bar's longest length
const POINT_PX = [2, 14]; // a point's size on screen: ~1.5 × the cloud's spacing, within these

// A round length near `mm` for a scale bar or an axis: 1, 2 or 5 × 10^k mm.
export function roundLength(mm) {
  const power = 10 ** Math.floor(Math.log10(mm));
  return [5, 2, 1].map((m) => m * power).find((length) => length <= mm) ?? power;
}

// A line drawn again over itself, SEAM_PX wide, in the selection's colour (a child of it:
// it moves and goes with the line).
function thickLine(line) {
  const geometry = new LineGeometry();
  geometry.setPositions(Array.from(line.geometry.attributes.position.array));
  const thick = new Line2(geometry, SEAM_HIGHLIGHT);
  thick.renderOrder = 6;
  thick.name = "selected-seam";
  line.add(thick);
  return thick;
}

// A label `heightM / 2` tall (a short one, "P3", `heightM` wide), as wide as its text.
function textSprite(text, colour, heightM) {
  const canvas = document.createElement("canvas");
  const context = canvas.getContext("2d");
  context.font = "bold 40px sans-serif";
  canvas.width = Math.max(128, Math.ceil(context.measureText(text).width) + 24);
  canvas.height = 64;
  context.fillStyle = "rgba(15, 23, 34, 0.75)";
  context.fillRect(0, 0, canvas.width, 64);
  context.fillStyle = colour;
  context.font = "bold 40px sans-serif";
  context.textAlign = "center";
  context.textBaseline = "middle";
  context.fillText(text, canvas.width / 2, 34);
  const material = new THREE.SpriteMaterial({ map: new THREE.CanvasTexture(canvas), depthTest: false });
  const sprite = new THREE.Sprite(material);
  sprite.scale.set((heightM * canvas.width) / 128, heightM / 2, 1);
  sprite.renderOrder = 20;
  return sprite;
}

// vista's base frame (X, Y, Z; +Z up) drawn at `origin` in glTF coordinates, `lengthM` long.
function baseAxes(origin, lengthM) {
  const group = new THREE.Group();
  group.name = "axes";
  const axes = [["X", 0xff5555, [1, 0, 0]], ["Y", 0x55dd55, [0, 0, -1]], ["Z", 0x5599ff, [0, 1, 0]]];
  for (const [name, colour, direction] of axes) {
    const end = new THREE.Vector3(...direction).multiplyScalar(lengthM).add(origin);
    const line = new THREE.Line(
      new THREE.BufferGeometry().setFromPoints([origin, end]),
      new THREE.LineBasicMaterial({ color: colour, depthTest: false }),
    );
    line.renderOrder = 20;
    const mm = Math.round(lengthM * 1000);
    const label = textSprite(`${name} ${mm >= 1000 ? `${mm / 1000} m` : `${mm} mm`}`, `#${colour.toString(16).padStart(6, "0")}`, lengthM * 0.3);
    label.position.copy(end).addScaledVector(new THREE.Vector3(...direction), lengthM * 0.15);
    group.add(line, label);
  }
  return group;
}

// A panel's id drawn where its top's centre is: the numbers a seam's "panels a → b" and
// its step's sign refer to.
function panelLabel(id, centroidMm) {
  const label = textSprite(`P${id}`, "#59d9ff", LABEL_M);
  const [x, y, z] = centroidMm;
  label.position.set(x / 1000, z / 1000, -y / 1000); // base frame (mm, +Z up) → glTF (m, +Y up)
  label.name = `label-panel-${id}`;
  label.userData.panelLabel = id;
  return label;
}

// The renderer and the camera fitted to the canvas's size on the page; false while it has none.
export function fitCanvas(renderer, camera, canvas) {
  const { clientWidth: width, clientHeight: height } = canvas;
  if (!width || !height) return false;
  renderer.setSize(width, height, false);
  camera.aspect = width / height;
  camera.updateProjectionMatrix();
  return true;
}

export class SceneView {
  // `scaleBar`: an element whose width and text show a round length at the orbit centre.
  constructor(canvas, onPick, { scaleBar = null } = {}) {
    this.canvas = canvas;
    this.onPick = onPick;
    this.scaleBar = scaleBar;
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
    this.seams = new Map();
    this.selected = null;
    this.selectedSeam = null;
    this.flight = null;
    this.root = null;
    this.unmeasured = []; // seam lines a measurement could not measure: why, on hover
    this.clouds = [];
    this.placing = null; // (base-frame point mm, normal) → void while a click places a finding
    canvas.addEventListener("click", (event) => (this.placing ? this.place(event) : this.pick(event)));
    canvas.addEventListener("pointermove", (event) => this.hover(event));
    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
    this.renderer.setAnimationLoop((time) => this.frame(time));
  }

  resize() {
    if (fitCanvas(this.renderer, this.camera, this.canvas)) this.invalidate();
    const size = this.renderer.getDrawingBufferSize(new THREE.Vector2());
    SEAM_HIGHLIGHT.resolution.copy(size); // its width is in pixels of the drawing buffer
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
    this.seams.clear();
    this.unmeasured = [];
    this.clouds = [];
    let points = 0;
    const labels = [];
    this.root.traverse((node) => {
      if (node.userData?.panel !== undefined && node.userData.centroid_mm) {
        labels.push(panelLabel(node.userData.panel, node.userData.centroid_mm));
      }
      if (node.userData?.seam !== undefined && node.isLine) {
        node.material.depthTest = false;
        node.renderOrder = 5;
        this.seams.set(node.userData.seam, { node });
        if (node.userData.unmeasured) this.unmeasured.push(node);
      }
      const id = node.userData?.defect_id;
      if (id !== undefined && node.isMesh) {
        node.material.depthTest = false;
        node.material.transparent = true; // drawn after the cloud, over it
        node.renderOrder = 10;
        this.markers.set(id, { node, material: node.material, scale: node.scale.clone() });
      }
      if (node.isPoints) {
        node.material.size = POINT_PX[0];
        node.material.sizeAttenuation = false;
        const count = node.geometry.attributes.position.count;
        node.geometry.computeBoundingBox();
        const size = node.geometry.boundingBox.getSize(new THREE.Vector3());
        // the mean spacing of points spread over the cloud's footprint (+Y up)
        this.clouds.push({ node, spacingM: Math.sqrt((size.x * size.z) / Math.max(count, 1)) });
        points += count;
      }
    });
    for (const label of labels) this.root.add(label);
    const box = new THREE.Box3().setFromObject(this.root);
    if (!box.isEmpty()) {
      const sizeMm = box.getSize(new THREE.Vector3()).length() * 1000;
      this.root.add(baseAxes(box.min.clone(), roundLength(sizeMm / 6) / 1000));
    }
    if (frame) this.frameAll();
    if (this.selected !== null) this.select(this.selected, false, this.selectedSeam);
    this.pendingMark = mark;
    this.invalidate();
    return { markers: this.markers.size, points, panels: labels.length, seams: this.seams.size, unmeasured: this.unmeasured.length };
  }

  // Over an unmeasured seam's line (within a few pixels on screen), the canvas's tooltip
  // says which seam and why it was not measured.
  hover(event) {
    const rect = this.canvas.getBoundingClientRect();
    const x = event.clientX - rect.left;
    const y = event.clientY - rect.top;
    let found = null;
    for (const node of this.unmeasured) {
      const position = node.geometry.attributes.position;
      let previous = null;
      for (let i = 0; i < position.count && !found; i += 1) {
        const point = new THREE.Vector3().fromBufferAttribute(position, i).applyMatrix4(node.matrixWorld);
        const here = this.toScreen(point, rect);
        if (here[0] !== null && previous && segmentDistance(x, y, previous, here) <= PICK_SLACK_PX) found = node;
        previous = here[0] === null ? null : here;
      }
      if (found) break;
    }
    const text = found ? unmeasuredText(found.userData) : "";
    if (this.canvas.title !== text) this.canvas.title = text;
  }

  frameAll() {
    const box = new THREE.Box3().setFromObject(this.root);
    const size = box.getSize(new THREE.Vector3()).length() || 1;
    const centre = box.getCenter(new THREE.Vector3());
    this.controls.target.copy(centre);
    // the whole part in view across and up, whatever the canvas's shape (a narrow one at
    // 1024 px cropped it): its bounding sphere fits the narrower of the two angles of view
    const halfUp = THREE.MathUtils.degToRad(this.camera.fov / 2);
    const halfAcross = Math.atan(Math.tan(halfUp) * this.camera.aspect);
    const distance = (0.5 * size) / Math.sin(Math.min(halfUp, halfAcross));
    this.camera.position.copy(centre).add(new THREE.Vector3(0, 0.5, 0.9).normalize().multiplyScalar(distance));
    this.camera.near = size / 1000;
    this.camera.far = size * 20;
    this.camera.updateProjectionMatrix();
  }

  // Highlights a defect's ring (and its seam's line, `seam` being the seam's id or null);
  // `fly`: the camera flies to it at a distance that fits the ring.
  select(defectId, fly = true, seam = null) {
    const previous = this.markers.get(this.selected);
    if (previous) {
      previous.node.material = previous.material;
      previous.node.scale.copy(previous.scale);
    }
    this.thickSeam?.removeFromParent();
    this.thickSeam = null;
    this.selected = defectId;
    this.selectedSeam = seam;
    this.invalidate();
    const marker = this.markers.get(defectId);
    if (!marker) return; // not on this scene: nor is its seam (another run's seam 0 is another seam)
    const seamLine = this.seams.get(seam);
    if (seamLine) this.thickSeam = thickLine(seamLine.node);
    marker.node.material = HIGHLIGHT;
    marker.node.scale.copy(marker.scale).multiplyScalar(1.25);
    if (fly) this.flyTo(marker.node);
  }

  // The camera looks at the node from along its normal (tilted a little), from where the
  // ring fills about a third of the view.
  flyTo(node) {
    const target = node.getWorldPosition(new THREE.Vector3());
    const [nx, ny, nz] = node.userData.normal || [0, 0, 1];
    const normal = new THREE.Vector3(nx, nz, -ny).normalize(); // base frame → glTF (+Y up)
    const halfView = Math.tan(THREE.MathUtils.degToRad(this.camera.fov / 2));
    const distance = Math.max(NEAREST_VIEW_M, (3 * node.scale.x) / halfView);
    const tilt = new THREE.Vector3(0, 0, 1).projectOnPlane(normal).normalize().multiplyScalar(0.35);
    const position = target.clone().add(normal.add(tilt).normalize().multiplyScalar(distance));
    this.camera.near = distance / 100;
    this.camera.updateProjectionMatrix();
    this.flight = {
      start: performance.now(),
      fromTarget: this.controls.target.clone(), toTarget: target,
      fromPosition: this.camera.position.clone(), toPosition: position,
    };
  }

  // A click picks the ring it is on or nearest to (on screen): the smallest ring wins where
  // rings nest. Rings are thin, so a click inside one or a few pixels off it counts.
  pick(event) {
    const rect = this.canvas.getBoundingClientRect();
    const x = event.clientX - rect.left;
    const y = event.clientY - rect.top;
    let best = null;
    for (const [id, { node }] of this.markers) {
      const centre = node.getWorldPosition(new THREE.Vector3());
      const edge = centre.clone().addScaledVector(new THREE.Vector3(1, 0, 0).applyQuaternion(this.camera.quaternion), node.scale.x);
      const [cx, cy] = this.toScreen(centre, rect);
      const [ex, ey] = this.toScreen(edge, rect);
      if (cx === null) continue;
      const radius = Math.hypot(ex - cx, ey - cy);
      if (Math.hypot(x - cx, y - cy) <= radius + PICK_SLACK_PX && (!best || radius < best.radius)) best = { id, radius };
    }
    if (best) this.onPick(best.id);
  }

  // The cloud's point under a click (the nearest to the eye among those within a few pixels
  // of the ray), in the base frame (mm), with the direction back to the eye as its normal:
  // where a finding placed by hand lies.
  place(event) {
    const rect = this.canvas.getBoundingClientRect();
    const ndc = new THREE.Vector2(((event.clientX - rect.left) / rect.width) * 2 - 1, -((event.clientY - rect.top) / rect.height) * 2 + 1);
    const raycaster = new THREE.Raycaster();
    raycaster.setFromCamera(ndc, this.camera);
    const distance = this.camera.position.distanceTo(this.controls.target);
    const halfView = Math.tan(THREE.MathUtils.degToRad(this.camera.fov / 2));
    raycaster.params.Points.threshold = (PICK_SLACK_PX * 2 * distance * halfView) / rect.height;
    const hits = raycaster.intersectObjects(this.clouds.map((c) => c.node), false);
    if (!hits.length) return;
    const hit = hits[0]; // its `point` lies on the ray: the cloud's own point is its vertex
    const p = new THREE.Vector3().fromBufferAttribute(hit.object.geometry.attributes.position, hit.index).applyMatrix4(hit.object.matrixWorld);
    const back = raycaster.ray.direction.clone().negate();
    const pointMm = [p.x * 1000, -p.z * 1000, p.y * 1000]; // glTF (m, +Y up) → base (mm, +Z up)
    const normal = [back.x, -back.z, back.y];
    const done = this.placing;
    this.placing = null;
    done(pointMm, normal);
  }

  toScreen(point, rect) {
    const ndc = point.clone().project(this.camera);
    if (ndc.z > 1) return [null, null]; // behind the camera
    return [((ndc.x + 1) / 2) * rect.width, ((1 - ndc.y) / 2) * rect.height];
  }

  // At the orbit centre's depth: the scale bar shows a round length, and points grow to
  // close the holes between them when the camera comes close.
  updateScale() {
    if (!this.canvas.clientHeight) return;
    const distance = this.camera.position.distanceTo(this.controls.target);
    const halfView = Math.tan(THREE.MathUtils.degToRad(this.camera.fov / 2));
    const pxPerMm = this.canvas.clientHeight / (2 * distance * halfView * 1000);
    for (const { node, spacingM } of this.clouds || []) {
      node.material.size = THREE.MathUtils.clamp(1.5 * spacingM * 1000 * pxPerMm, ...POINT_PX);
    }
    if (!this.scaleBar) return;
    const lengthMm = roundLength(SCALE_BAR_PX / pxPerMm);
    this.scaleBar.style.width = `${Math.round(lengthMm * pxPerMm)}px`;
    this.scaleBar.dataset.mm = String(lengthMm);
    this.scaleBar.textContent = lengthMm >= 1000 ? `${lengthMm / 1000} m` : `${lengthMm} mm`;
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
    this.updateScale();
    this.renderer.render(this.scene, this.camera);
    if (this.pendingMark && this.root) {
      performance.mark(this.pendingMark);
      this.pendingMark = null;
      this.canvas.dataset.drawn = "true";
    }
  }
}

// The distance on screen from (x, y) to the segment a–b (pixels).
function segmentDistance(x, y, [ax, ay], [bx, by]) {
  const dx = bx - ax;
  const dy = by - ay;
  const t = Math.max(0, Math.min(1, ((x - ax) * dx + (y - ay) * dy) / Math.max(dx * dx + dy * dy, 1e-9)));
  return Math.hypot(x - (ax + t * dx), y - (ay + t * dy));
}

// What an unmeasured seam's line says on hover.
export function unmeasuredText({ seam, panels, unmeasured }) {
  const between = Array.isArray(panels) ? ` (P${panels[0]}–P${panels[1]})` : "";
  return `seam ${seam}${between} unmeasured: ${unmeasured}`;
}
