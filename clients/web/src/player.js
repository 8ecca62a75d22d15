// A job's scene.glb on its run page (GET /jobs/{id}/scene.glb): a path, depth clouds, or a
// drive whose scans and boxes move frame by frame — played from the file's own animation
// `frames` (play, pause, step, scrub), with the frame rate it reaches.
import * as THREE from "three";
import { GLTFLoader } from "three/examples/jsm/loaders/GLTFLoader.js";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
import { Line2 } from "three/examples/jsm/lines/Line2.js";
import { LineGeometry } from "three/examples/jsm/lines/LineGeometry.js";
import { LineMaterial } from "three/examples/jsm/lines/LineMaterial.js";
import { el } from "./dom.js";
import { fitCanvas, roundLength } from "./scene.js";

const POINT_PX = 2;
const GRID_CELLS = 10; // the ground grid's cells across the scene's longer side
const PATH_PX = 3; // a path's width on screen (a plain WebGL line is one pixel)
const LABEL_SCREEN = 0.05; // a label's height, a fraction of the view's

// A text label drawn in the scene, always facing the viewer: `height` tall in metres, or
// with `onScreen`, that fraction of the view whatever the distance.
function label(text, colour, height, onScreen = false) {
  const canvas = document.createElement("canvas");
  const context = canvas.getContext("2d");
  context.font = "bold 36px sans-serif";
  canvas.width = Math.ceil(context.measureText(text).width) + 16;
  canvas.height = 48;
  context.font = "bold 36px sans-serif";
  context.fillStyle = "rgba(15, 23, 34, 0.7)";
  context.fillRect(0, 0, canvas.width, canvas.height);
  context.fillStyle = colour;
  context.textBaseline = "middle";
  context.fillText(text, 8, 26);
  const sprite = new THREE.Sprite(new THREE.SpriteMaterial({ map: new THREE.CanvasTexture(canvas), depthTest: false, sizeAttenuation: !onScreen }));
  sprite.scale.set((height * canvas.width) / canvas.height, height, 1);
  sprite.renderOrder = 30;
  return sprite;
}

function hex(colour) {
  return `#${colour.getHexString()}`;
}

export class JobPlayer {
  constructor(host) {
    this.canvas = el("canvas", { class: "player-canvas", "aria-label": "the job's 3D scene" });
    this.frameLabel = el("span", { class: "muted", id: "player-frame" }, "");
    this.rate = el("span", { class: "muted", id: "player-fps" }, "");
    this.playButton = el("button", { id: "player-play", onclick: () => this.toggle() }, "▶ play");
    this.slider = el("input", { type: "range", min: "0", max: "0", value: "0", id: "player-scrub", "aria-label": "frame" });
    this.slider.addEventListener("input", () => this.show(Number(this.slider.value)));
    this.controlsBar = el(
      "div", { class: "player-controls" },
      el("button", { id: "player-back", title: "previous frame", onclick: () => this.step(-1) }, "‹ frame"),
      this.playButton,
      el("button", { id: "player-next", title: "next frame", onclick: () => this.step(1) }, "frame ›"),
      this.slider, this.frameLabel, this.rate,
    );
    this.controlsBar.hidden = true; // until a scene with frames is loaded
    this.legend = el("ul", { class: "legend player-legend", "aria-label": "legend" });
    this.scaleNote = el("span", { class: "muted", id: "player-scale" }, "");
    this.picker = el("select", { id: "player-pick", "aria-label": "which one is shown", hidden: "" });
    this.picker.addEventListener("change", () => this.pick(this.picker.value));
    host.append(
      el("div", { class: "player-tools" }, this.picker, this.scaleNote),
      el("div", { class: "player-box" }, this.canvas, el("details", { class: "legend-box", open: "" }, el("summary", {}, "legend"), this.legend)),
      this.controlsBar,
    );
    this.renderer = new THREE.WebGLRenderer({ canvas: this.canvas, antialias: false });
    this.renderer.setPixelRatio(Math.min(devicePixelRatio, 2));
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0x0f1722);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x445566, 2.0));
    this.camera = new THREE.PerspectiveCamera(50, 1, 0.05, 2000);
    this.orbit = new OrbitControls(this.camera, this.canvas);
    this.orbit.addEventListener("change", () => { this.dirty = true; });
    this.frames = 0;
    this.frameS = 0.1;
    this.frame = 0;
    this.playing = false;
    this.drawn = [];
    this.pickable = [];
    new ResizeObserver(() => this.resize()).observe(this.canvas);
    this.resize();
    this.renderer.setAnimationLoop((time) => this.tick(time));
  }

  async load(arrayBuffer) {
    const gltf = await new GLTFLoader().parseAsync(arrayBuffer, "");
    this.root = gltf.scene;
    this.scene.add(this.root);
    this.root.traverse((node) => {
      if (node.isPoints) {
        node.material.size = POINT_PX;
        node.material.sizeAttenuation = false;
      }
    });
    const extras = gltf.parser.json.asset.extras || {};
    this.frameS = extras.frame_s || 0.1;
    const clip = gltf.animations.find((a) => a.name === "frames");
    if (clip) {
      this.mixer = new THREE.AnimationMixer(this.root);
      this.action = this.mixer.clipAction(clip);
      this.action.play();
      this.action.paused = true;
      this.frames = Math.max(1, Math.round(clip.duration / this.frameS));
    }
    this.slider.max = String(Math.max(0, this.frames - 1));
    this.controlsBar.hidden = !clip;
    this.drawFrameOfReference();
    this.markEnds();
    this.drawLegend();
    this.offerPicker(clip);
    const box = new THREE.Box3().setFromObject(this.root);
    const size = box.getSize(new THREE.Vector3()).length() || 1;
    const centre = box.getCenter(new THREE.Vector3());
    this.orbit.target.copy(centre);
    // a still scene (a path, clouds) seen whole; a drive from nearer, where its boxes are
    const distance = clip ? 0.67 * size : 0.6 * size / Math.sin((this.camera.fov * Math.PI) / 360);
    this.camera.position.copy(centre).add(new THREE.Vector3(-0.35, 0.45, 0.35).normalize().multiplyScalar(distance));
    this.camera.near = size / 2000;
    this.camera.far = size * 20;
    this.camera.updateProjectionMatrix();
    this.orbit.update(); // turns the camera to the target
    this.show(0);
    return { frames: this.frames, nodes: this.root.children.length };
  }

  // Axes with their unit at the scene's corner and a ground grid under it, its cell a round
  // length: what a metre looks like here.
  drawFrameOfReference() {
    const box = new THREE.Box3().setFromObject(this.root);
    if (box.isEmpty()) return;
    const size = box.getSize(new THREE.Vector3());
    const side = Math.max(size.x, size.z, 1e-3);
    const cellM = roundLength((side * 1000) / GRID_CELLS) / 1000;
    const cells = Math.ceil(side / cellM) + 2;
    const grid = new THREE.GridHelper(cells * cellM, cells, 0x4b5d73, 0x2a3646);
    const centre = box.getCenter(new THREE.Vector3());
    grid.position.set(centre.x, box.min.y, centre.z);
    grid.name = "grid";
    const axisM = cellM * 2;
    const axes = new THREE.Group();
    axes.name = "axes";
    const origin = new THREE.Vector3(box.min.x, box.min.y, box.max.z);
    // the scene's frame is +Z up (glTF +Y): x, y across the ground, z up
    for (const [name, colour, direction] of [["x", 0xff5555, [1, 0, 0]], ["y", 0x55dd55, [0, 0, -1]], ["z", 0x5599ff, [0, 1, 0]]]) {
      const end = new THREE.Vector3(...direction).multiplyScalar(axisM).add(origin);
      axes.add(new THREE.Line(new THREE.BufferGeometry().setFromPoints([origin, end]), new THREE.LineBasicMaterial({ color: colour, depthTest: false })));
      const tag = label(`${name} ${axisM < 1 ? `${axisM * 1000} mm` : `${axisM} m`}`, `#${colour.toString(16).padStart(6, "0")}`, LABEL_SCREEN * 0.7, true);
      tag.position.copy(end);
      axes.add(tag);
    }
    this.scene.add(grid, axes);
    this.scaleNote.textContent = `grid: ${cellM < 1 ? `${cellM * 1000} mm` : `${cellM} m`} a cell · axes ${axisM < 1 ? `${axisM * 1000} mm` : `${axisM} m`} long`;
    this.canvas.dataset.gridM = String(cellM);
  }

  // A path (a line strip, not a box) is drawn PATH_PX wide, its start and end marked; the
  // first path's ends are named (the others start and end where their dots are).
  markEnds() {
    const paths = [];
    this.root.traverse((node) => {
      // a path: an open strip (not a box's wire, not an outline's loop)
      if (node.isLine && !node.isLineLoop && !node.isLineSegments && !node.userData.size_m && node.geometry.attributes.position.count > 2) paths.push(node);
    });
    this.fatLines = [];
    paths.forEach((path, index) => {
      const position = path.geometry.attributes.position;
      const geometry = new LineGeometry();
      geometry.setPositions(Array.from(position.array));
      const material = new LineMaterial({ color: path.material.color, linewidth: PATH_PX });
      const fat = new Line2(geometry, material);
      fat.applyMatrix4(path.matrixWorld);
      this.scene.add(fat);
      this.fatLines.push(material);
      const ends = [0, position.count - 1].map((i) => new THREE.Vector3().fromBufferAttribute(position, i).applyMatrix4(path.matrixWorld));
      ends.forEach((where, end) => {
        const dot = label("●", end ? "#ff8a80" : "#7CFC9A", LABEL_SCREEN * 0.6, true);
        dot.position.copy(where);
        this.scene.add(dot);
        if (index === 0) {
          const tag = label(end ? "end" : "start", end ? "#ff8a80" : "#7CFC9A", LABEL_SCREEN, true);
          tag.center.set(end ? -0.15 : 1.15, 0.5); // beside the dot, not on it
          tag.position.copy(where);
          this.scene.add(tag);
        }
      });
    });
    this.canvas.dataset.pathEnds = String(paths.length);
    this.resize();
  }

  // Every colour drawn, said: each named line or box material, and what the points'
  // colours mean (the scene's own legend, from its job node's extras).
  drawLegend() {
    const entries = new Map();
    this.root.traverse((node) => {
      const material = node.material;
      // boxes share "wire-box-N" materials: the scene's own legend says what they are
      if ((node.isLine || node.isMesh) && material?.name && material.color && !material.name.startsWith("wire-box") && !entries.has(material.name)) {
        entries.set(material.name, el("li", {}, el("span", { class: "swatch line", style: `--swatch:${hex(material.color)}` }), material.name.replaceAll("-", " ")));
      }
    });
    const job = this.root.children.find((n) => n.name.startsWith("job-")) || this.root;
    for (const item of job.userData?.legend || []) {
      const swatch = item.gradient
        ? el("span", { class: "swatch gradient", style: `background: linear-gradient(90deg, ${item.gradient.join(", ")})` })
        : el("span", { class: "swatch", style: `background:${item.colour}` });
      entries.set(item.text, el("li", {}, swatch, item.text));
    }
    this.legend.replaceChildren(...entries.values());
    this.legend.closest("details").hidden = entries.size === 0;
  }

  // Frames that are not a sequence (a depth run's images, each in its own camera frame):
  // one at a time, picked by name.
  offerPicker(clip) {
    const clouds = [];
    if (!clip) this.root.traverse((node) => { if (node.isPoints && node.name.startsWith("cloud-")) clouds.push(node); });
    this.pickable = clouds.length > 1 ? clouds : [];
    this.picker.hidden = this.pickable.length === 0;
    if (!this.pickable.length) return;
    this.picker.replaceChildren(...clouds.map((n) => el("option", { value: n.name }, n.userData.image || n.name.slice(6))));
    this.pick(clouds[0].name);
  }

  pick(name) {
    for (const node of this.pickable) node.visible = node.name === name;
    this.picker.value = name;
    this.canvas.dataset.shown = name;
    this.canvas.dataset.points = String(this.pickable.find((n) => n.name === name).geometry.attributes.position.count);
    this.dirty = true;
  }

  // Frame `k`: the animation sampled half way through it (each scan is shown for its frame).
  show(k) {
    this.frame = Math.max(0, Math.min(this.frames - 1, k));
    if (this.mixer) {
      this.action.time = (this.frame + 0.5) * this.frameS; // a paused action holds this pose
      this.mixer.update(0);
    }
    let shown = 0;
    let boxes = 0;
    this.root?.traverse((node) => {
      if (!node.isPoints && !node.isLine) return;
      if (this.pickable?.includes(node)) return; // one cloud at a time: the picker's
      // a scan or a box out of its frame is scaled to nothing: leave it out of the draw
      node.visible = node.scale.x > 0;
      if (!node.visible) return;
      if (node.isPoints) shown += node.geometry.attributes.position.count;
      else if (node.userData.size_m) boxes += 1;
    });
    if (!this.pickable?.length) this.canvas.dataset.points = String(shown);
    this.canvas.dataset.boxes = String(boxes);
    this.slider.value = String(this.frame);
    this.frameLabel.textContent = this.frames ? `frame ${this.frame + 1} / ${this.frames}` : "";
    this.dirty = true;
  }

  step(by) {
    this.pause();
    this.show(this.frame + by);
  }

  toggle() {
    if (this.playing) this.pause();
    else this.play();
  }

  play() {
    if (!this.frames) return;
    this.playing = true;
    this.playButton.textContent = "⏸ pause";
    this.started = null;
  }

  pause() {
    this.playing = false;
    this.playButton.textContent = "▶ play";
  }

  resize() {
    if (fitCanvas(this.renderer, this.camera, this.canvas)) this.dirty = true;
    const size = this.renderer.getDrawingBufferSize(new THREE.Vector2());
    for (const material of this.fatLines || []) material.resolution.copy(size); // px widths
  }

  tick(time) {
    if (this.playing) {
      if (this.started === null) this.started = { time, frame: this.frame };
      const due = (this.started.frame + Math.floor((time - this.started.time) / 1000 / this.frameS)) % this.frames;
      if (due !== this.frame) this.show(due);
    }
    if (!this.dirty) return;
    this.dirty = false;
    this.renderer.render(this.scene, this.camera);
    // the frames drawn in the last second: what a viewer gets while playing
    this.drawn.push(time);
    while (this.drawn.length && this.drawn[0] < time - 1000) this.drawn.shift();
    if (this.playing) {
      this.canvas.dataset.shownPerS = String(this.drawn.length);
      this.rate.textContent = `${this.drawn.length} frames drawn in the last second`;
    }
    this.canvas.dataset.drawn = String(Number(this.canvas.dataset.drawn || 0) + 1);
    if (this.onDrawn && this.root) {
      this.onDrawn();
      this.onDrawn = null;
    }
  }

  dispose() {
    this.renderer.setAnimationLoop(null);
    this.renderer.dispose();
  }
}
