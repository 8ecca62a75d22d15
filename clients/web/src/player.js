// A job's scene.glb on its run page (GET /jobs/{id}/scene.glb): a path, depth clouds, or a
// drive whose scans and boxes move frame by frame — played from the file's own animation
// `frames` (play, pause, step, scrub), with the frame rate it reaches.
import * as THREE from "three";
import { GLTFLoader } from "three/examples/jsm/loaders/GLTFLoader.js";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
import { el } from "./dom.js";
import { fitCanvas } from "./scene.js";

const POINT_PX = 2;

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
    host.append(el("div", { class: "player-box" }, this.canvas), this.controlsBar);
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
      // a scan or a box out of its frame is scaled to nothing: leave it out of the draw
      node.visible = node.scale.x > 0;
      if (!node.visible) return;
      if (node.isPoints) shown += node.geometry.attributes.position.count;
      else if (node.userData.size_m) boxes += 1;
    });
    this.canvas.dataset.points = String(shown);
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
