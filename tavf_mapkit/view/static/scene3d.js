// The 3D view of a build (three.js, vendored): the glTF mesh tiles and the collision world's OBJ bodies,
// orbit or fly, and a drive replayed in it (ego, SUMO vehicles and pedestrians, UDM objects).
// Everything is placed in the glTF frame of the mesh's origin: (X, Y, Z) = (x - ox, z - oz, -(y - oy)).
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { FlyControls } from "three/addons/controls/FlyControls.js";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { OBJLoader } from "three/addons/loaders/OBJLoader.js";

const COLLISION_COLOURS = { road: 0x4dabf7, roadside: 0x74c0fc, curb: 0xf783ac, building: 0xffd43b,
                            object: 0xa9e34b, signal: 0xff6b6b };
const UDM_COLOURS = [0xadb5bd, 0xadb5bd, 0x4dabf7, 0xffa94d, 0xff6b6b];
const EGO = { length: 4.97, width: 1.96, height: 1.45 };  // the twin's Tesla Model S
const PARALLEL = 6;  // tiles loaded at once

// Whether this browser draws in software (no GPU: SwiftShader in a headless chromium or a VM, Mesa's llvmpipe):
// then every frame of the page -- WebGL, the 2D map's canvases, the compositing -- costs CPU, ~50 ms of a core
// per live update with antialiasing, on a machine whose other core runs the simulation.
export function rendersInSoftware() {
  const probe = document.createElement("canvas");
  const gl = probe.getContext("webgl2") || probe.getContext("webgl");
  if (!gl) return true;
  const info = gl.getExtension("WEBGL_debug_renderer_info");
  const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
  const lose = gl.getExtension("WEBGL_lose_context");
  if (lose) lose.loseContext();  // browsers keep a few contexts only: give this one back at once
  return /swiftshader|llvmpipe|softpipe|software|basic render/i.test(name);
}

export class MapkitScene3D {
  constructor(element, data, options) {
    this.element = element;
    this.data = data;
    this.origin = data.origin;
    this.software = Boolean(options && options.software);
    // preserveDrawingBuffer: the canvas can be read back (screenshots, tests); no multisampling in software,
    // where it took most of a frame's time
    this.renderer = new THREE.WebGLRenderer({ antialias: !this.software, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio || 1);
    element.appendChild(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0xdde4ec);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x667080, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(300, 800, 200);
    this.scene.add(sun);
    this.camera = new THREE.PerspectiveCamera(50, 1, 0.3, 50000);
    this.meshGroup = new THREE.Group();
    this.collisionGroup = new THREE.Group();
    this.collisionGroup.visible = false;
    this.replayGroup = new THREE.Group();
    this.scene.add(this.meshGroup, this.collisionGroup, this.replayGroup);
    this.clock = new THREE.Clock();
    this.follow = false;
    this.run = null;
    this.actors = new Map();
    this.udmMaterials = new Map();
    this.udmGeometry = new THREE.BoxGeometry(1.5, 1.5, 1.5);
    // render on demand: a frame is asked for (this.dirty = true) when something changed -- the camera, a tile
    // loaded, the replay's or the live drive's time -- and drawn at the next animation frame; no loop runs
    // while nothing changes (fly mode excepted: its keys move the camera every frame), so a page left open
    // takes no core, not even to wake up 60 times a second
    this.frameAsked = false;
    this.frames = 0;  // frames drawn (tests, benchmarks)
    this.drawFrame = () => {
      this.frameAsked = false;
      if (this.controls.isFlyControls) {
        this.controls.update(this.clock.getDelta());  // dispatches "change" (dirty) when it moved the camera
        this.askFrame();
      }
      if (!this._dirty) return;
      this._dirty = false;
      this.renderer.render(this.scene, this.camera);
      this.frames += 1;
    };
    this._dirty = false;
    this.fitCamera();
    this.useOrbit();
    this.addToolbar();
    new ResizeObserver(() => this.resize()).observe(element);
    this.resize();
    this.loaded = this.loadAll();
  }

  get dirty() { return this._dirty; }

  set dirty(value) {
    this._dirty = Boolean(value);
    if (value) this.askFrame();
  }

  askFrame() {
    if (this.frameAsked) return;
    this.frameAsked = true;
    requestAnimationFrame(this.drawFrame);
  }

  toScene(x, y, z) {
    return new THREE.Vector3(x - this.origin[0], (z || 0) - this.origin[2], -(y - this.origin[1]));
  }

  fitCamera() {
    const b = this.data.bounds || [-100, -100, 100, 100];
    const centre = this.toScene((b[0] + b[2]) / 2, (b[1] + b[3]) / 2, 0);
    const size = Math.max(b[2] - b[0], b[3] - b[1], 50);
    this.target = centre;
    this.camera.position.set(centre.x + size * 0.35, size * 0.55, centre.z + size * 0.55);
    this.camera.lookAt(centre);
  }

  useOrbit() {
    if (this.controls) this.controls.dispose();
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.target.copy(this.target);
    this.controls.maxPolarAngle = Math.PI * 0.495;
    this.controls.addEventListener("change", () => { this.dirty = true; });
    this.controls.update();
    this.dirty = true;
  }

  useFly() {
    if (this.controls) this.controls.dispose();
    this.controls = new FlyControls(this.camera, this.renderer.domElement);
    this.controls.movementSpeed = 40;
    this.controls.rollSpeed = 0.6;
    this.controls.dragToLook = true;
    this.controls.addEventListener("change", () => { this.dirty = true; });
    this.clock.getDelta();  // no jump for the time spent in orbit mode
    this.askFrame();
  }

  addToolbar() {
    const bar = document.createElement("div");
    bar.className = "toolbar3d";
    bar.innerHTML =
      "<label><input type='radio' name='nav3d' value='orbit' checked> orbit</label>" +
      "<label title='W/S forward/back, A/D sideways, R/F up/down, Q/E roll; drag to look'>" +
      "<input type='radio' name='nav3d' value='fly'> fly</label>" +
      "<label><input type='checkbox' id='show-mesh' checked> mesh</label>" +
      "<label><input type='checkbox' id='show-collision'> collision world</label>" +
      "<label><input type='checkbox' id='follow-ego'> follow ego</label>" +
      "<span id='scene-status'></span>";
    this.element.appendChild(bar);
    for (const radio of bar.querySelectorAll("input[name=nav3d]")) {
      radio.addEventListener("change", () => (radio.value === "fly" ? this.useFly() : this.useOrbit()));
    }
    bar.querySelector("#show-mesh").addEventListener("change", (e) => {
      this.meshGroup.visible = e.target.checked; this.dirty = true;
    });
    bar.querySelector("#show-collision").addEventListener("change",
      (e) => { this.collisionGroup.visible = e.target.checked; this.dirty = true; });
    bar.querySelector("#follow-ego").addEventListener("change", (e) => { this.follow = e.target.checked; });
    this.status = bar.querySelector("#scene-status");
  }

  resize() {
    const width = Math.max(1, this.element.clientWidth), height = Math.max(1, this.element.clientHeight);
    this.renderer.setSize(width, height);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    this.dirty = true;
  }

  async loadAll() {
    const gltf = new GLTFLoader(), obj = new OBJLoader();
    const tiles = this.data.mesh.tiles, bodies = this.data.collision.bodies;
    const co = this.data.collision.origin;
    // collision OBJ: local minus the world's origin, z up -> the glTF frame of the mesh's origin
    this.collisionGroup.rotation.x = -Math.PI / 2;
    this.collisionGroup.position.copy(this.toScene(co[0], co[1], co[2]));
    const jobs = [];
    for (const tile of tiles) {
      jobs.push(async () => {
        if (this.data.mesh.format === "obj") this.meshGroup.add(await obj.loadAsync(tile.url));
        else this.meshGroup.add((await gltf.loadAsync(tile.url)).scene);
      });
    }
    for (const body of bodies) {
      jobs.push(async () => {
        const object = await obj.loadAsync(body.url);
        const material = new THREE.MeshBasicMaterial({ color: COLLISION_COLOURS[body.group] || 0xcccccc,
                                                        wireframe: true });
        object.traverse((child) => { if (child.isMesh) child.material = material; });
        this.collisionGroup.add(object);
      });
    }
    let done = 0, failed = 0;
    const total = jobs.length;
    const worker = async () => {
      while (jobs.length) {
        const job = jobs.shift();
        try { await job(); } catch (error) { failed += 1; console.warn("3D: " + error); }
        done += 1;
        this.dirty = true;
        if (this.status) this.status.textContent = done < total ? "loading " + done + "/" + total : "";
      }
    };
    await Promise.all(Array.from({ length: PARALLEL }, worker));
    if (this.status && failed) this.status.textContent = failed + " of " + total + " files failed to load";
    return { tiles: tiles.length, bodies: bodies.length, failed };
  }

  // --- replay ---
  showRun(run) {
    this.dirty = true;
    this.run = run;
    this.replayGroup.clear();
    this.actors = new Map();
    if (!run) return;
    this.track = new THREE.Line(new THREE.BufferGeometry().setFromPoints(this.trackPoints(run)),
                                new THREE.LineBasicMaterial({ color: 0x2b8a3e }));
    this.replayGroup.add(this.track);
    this.ego = new THREE.Mesh(new THREE.BoxGeometry(EGO.length, EGO.height, EGO.width),
                              new THREE.MeshStandardMaterial({ color: 0x2f9e44 }));
    this.ego.name = "ego";
    this.replayGroup.add(this.ego);
    this.udm = new THREE.Group();
    this.replayGroup.add(this.udm);
  }

  trackPoints(run) {
    const track = [];
    for (let i = 0; i < run.ego.t.length; i++) {
      if (run.ego.x[i] !== null) track.push(this.toScene(run.ego.x[i], run.ego.y[i], (run.ego.z[i] || 0) + 0.15));
    }
    return track;
  }

  refreshTrack() {  // the run's ego arrays grew (a live drive): a new line geometry
    const old = this.track.geometry;
    this.track.geometry = new THREE.BufferGeometry().setFromPoints(this.trackPoints(this.run));
    old.dispose();
    this.dirty = true;
  }

  place(mesh, x, y, z, yaw, lift) {
    mesh.position.copy(this.toScene(x, y, (z || 0) + lift));
    mesh.rotation.set(0, yaw || 0, 0);  // yaw counter-clockwise from east about local z = about scene +Y
  }

  showTime(index) {
    this.dirty = true;
    const run = this.run;
    if (!run || run.ego.x[index] === null) return;
    const ego = run.ego;
    this.place(this.ego, ego.x[index], ego.y[index], ego.z[index], ego.yaw[index], EGO.height / 2);
    if (this.follow && this.controls.target) {
      const shift = this.ego.position.clone().sub(this.controls.target);
      this.controls.target.add(shift);
      this.camera.position.add(shift);
      this.controls.update();
    }
    const t = ego.t[index];
    if (run.traffic && run.traffic.frames.length) {
      const frames = run.traffic.frames;
      const frame = frames[window.MapkitIndexAt(frames.map((f) => f.t), t)];
      const seen = new Set();
      for (let k = 0; k < frame.ids.length; k++) {
        const id = frame.ids[k];
        seen.add(id);
        let actor = this.actors.get(id);
        if (!actor) {
          const person = frame.person[k];
          const geometry = person ? new THREE.CylinderGeometry(0.3, 0.3, 1.7, 10)
            : new THREE.BoxGeometry(frame.length[k] || 4.5, 1.5, frame.width[k] || 1.8);
          actor = new THREE.Mesh(geometry, new THREE.MeshStandardMaterial({ color: person ? 0xf06595 : 0x22b8cf }));
          actor.userData.lift = person ? 0.85 : 0.75;
          this.actors.set(id, actor);
          this.replayGroup.add(actor);
        }
        actor.visible = true;
        // SUMO's z is the body's centre height already for vehicles (0.75) and people (0.86)
        this.place(actor, frame.x[k], frame.y[k], 0, frame.yaw[k], actor.userData.lift);
      }
      for (const [id, actor] of this.actors) if (!seen.has(id)) actor.visible = false;
    }
    this.udm.clear();  // one shared box and one material per layer: nothing to dispose of at every update
    const answers = (run.udm || []).filter((a) => a.t !== null && a.t <= t && a.status === "ok");
    if (answers.length) {
      for (const obj of answers[answers.length - 1].objects) {
        if (obj.x === undefined) continue;
        const cube = new THREE.Mesh(this.udmGeometry, this.udmMaterial(obj.layer));
        this.place(cube, obj.x, obj.y, ego.z[index], 0, 0.75);
        this.udm.add(cube);
      }
    }
  }

  udmMaterial(layer) {
    let material = this.udmMaterials.get(layer);
    if (!material) {
      material = new THREE.MeshStandardMaterial({ color: UDM_COLOURS[layer] || 0xadb5bd });
      this.udmMaterials.set(layer, material);
    }
    return material;
  }
}
