// The 3D view of the cell (three.js, loaded only when the build copied it: assets/vendor.json).
// World frame z up, metres. Poses are [x, y, z, A, B, C] with R = Rz(C)·Ry(B)·Rx(A) (pnp's
// convention, docs/cell-file.md) or {xyz, rpy}. A robot is drawn from its model's DH table
// (GET /api/robot/<model>, the backend's copy of src/kinematics — never duplicated here) and
// the joints of `world` messages. Rendering happens on demand: a world update or a camera
// move schedules one frame.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const kDefaultToolLength = 0.15;  // m, when the world does not give the tool's TCP
const kDefaultObjectSize = [0.04, 0.04, 0.04];
const kMaxObjects = 1024;
const kMaxRobots = 16;
// Frame pacing: ≤ 60 frames/s on a GPU; ≤ 10 with software WebGL (no GPU: the frame is drawn
// and then copied to the compositor on the page's main thread).
const kMinFrameIntervalMs = 1000 / 60;
const kMinSoftwareFrameIntervalMs = 100;

function poseMatrix(pose) {
  let xyz = [0, 0, 0];
  let abc = [0, 0, 0];
  if (Array.isArray(pose)) {
    xyz = pose.slice(0, 3);
    abc = pose.slice(3, 6);
  } else if (pose && typeof pose === 'object') {
    xyz = pose.xyz || [pose.x, pose.y, pose.z];
    abc = pose.rpy || [pose.a, pose.b, pose.c];
  }
  const n = (v) => (Number.isFinite(Number(v)) ? Number(v) : 0);
  const matrix = new THREE.Matrix4().makeRotationFromEuler(
      new THREE.Euler(n(abc[0]), n(abc[1]), n(abc[2]), 'ZYX'));
  matrix.setPosition(n(xyz[0]), n(xyz[1]), n(xyz[2]));
  return matrix;
}

function setPose(object, pose) {
  object.matrixAutoUpdate = false;
  object.matrix.copy(poseMatrix(pose));
  object.matrixWorldNeedsUpdate = true;
}

function dhRows(model) {
  const rows = Array.isArray(model) ? model : model?.dh;
  if (!Array.isArray(rows) || rows.length === 0 || rows.length > 12) return null;
  const parsed = rows.map((row) => {
    const r = Array.isArray(row) ? { a: row[0], d: row[1], alpha: row[2], thetaOffset: row[3] } : row;
    return { a: Number(r.a) || 0, d: Number(r.d) || 0, alpha: Number(r.alpha) || 0,
             thetaOffset: Number(r.thetaOffset ?? r.theta ?? 0) || 0 };
  });
  return parsed;
}

// A cylinder of radius r between two points (updated in place each frame).
class Segment {
  constructor(parent, radius, material) {
    this.mesh = new THREE.Mesh(new THREE.CylinderGeometry(radius, radius, 1, 16), material);
    parent.add(this.mesh);
  }

  set(from, to) {
    const direction = new THREE.Vector3().subVectors(to, from);
    const length = direction.length();
    this.mesh.visible = length > 1e-6;
    if (!this.mesh.visible) return;
    this.mesh.position.copy(from).addScaledVector(direction, 0.5);
    this.mesh.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), direction.normalize());
    this.mesh.scale.set(1, length, 1);
  }
}

function toolMesh(length, material) {
  // The changer plate, then the tool body along the flange's z, ending at the TCP.
  const group = new THREE.Group();
  const plate = new THREE.Mesh(new THREE.CylinderGeometry(0.035, 0.035, 0.02, 20), material);
  plate.rotation.x = Math.PI / 2;
  plate.position.z = 0.01;
  const body = new THREE.Mesh(new THREE.BoxGeometry(0.05, 0.05, Math.max(length - 0.02, 0.01)), material);
  body.position.z = 0.02 + Math.max(length - 0.02, 0.01) / 2;
  group.add(plate, body);
  return group;
}

export class CellView {
  constructor(container, statusNode, { fetchRobotModel, fetchRobotModels }) {
    this.fetchRobotModels = fetchRobotModels;
    this.knownModels = null;  // GET /api/robots, asked once when a robot has no model
    this.container = container;
    this.statusNode = statusNode;
    // Resolved after the first frame: three.js compiles its shaders then, which takes long
    // with software WebGL; the page counts as settled only after it.
    this.firstFrame = new Promise((resolve) => { this.resolveFirstFrame = resolve; });
    this.fetchRobotModel = fetchRobotModel;
    this.models = new Map();    // model name -> DH rows | 'loading' | 'failed'
    this.robots = new Map();    // robot name -> {group, segments, joints, flange, toolName, toolObject}
    this.guessedModels = new Set();  // robots whose model was taken from their name
    this.objects = new Map();   // object name -> mesh
    this.staticKey = '';
    this.frameScheduled = false;
    this.world = null;
  }

  // False (with a note in the page) when the browser has no WebGL.
  start() {
    const canvas = document.createElement('canvas');
    // No multisampling: software WebGL (no GPU) spends most of a frame on it.
    const context = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: false });
    if (!context) {
      this.statusNode.textContent = '3D view unavailable: this browser offers no WebGL 2.';
      return false;
    }
    const debugInfo = context.getExtension('WEBGL_debug_renderer_info');
    const rendererName = debugInfo ? String(context.getParameter(debugInfo.UNMASKED_RENDERER_WEBGL)) : '';
    this.software = /swiftshader|llvmpipe|software/i.test(rendererName);
    this.minFrameIntervalMs = this.software ? kMinSoftwareFrameIntervalMs : kMinFrameIntervalMs;
    this.renderer = new THREE.WebGLRenderer({ canvas, context, antialias: false });
    // Software WebGL draws every pixel on the CPU, on the page's only thread: half the
    // resolution (a quarter of the pixels) keeps a frame from delaying the live updates.
    this.renderer.setPixelRatio(this.software ? 0.5 : Math.min(window.devicePixelRatio || 1, 2));
    this.container.append(canvas);

    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0xeef1f5);
    this.camera = new THREE.PerspectiveCamera(45, 1, 0.01, 50);
    this.camera.up.set(0, 0, 1);
    this.camera.position.set(0.95, -1.15, 0.85);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.target.set(-0.05, 0.12, 0.05);
    this.controls.update();
    this.controls.addEventListener('change', () => this.requestFrame());

    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8892a0, 2.0));
    const sun = new THREE.DirectionalLight(0xffffff, 1.5);
    sun.position.set(1, -1, 2);
    this.scene.add(sun);
    const grid = new THREE.GridHelper(2, 20, 0xb8c0cc, 0xd5dae1);
    grid.rotation.x = Math.PI / 2;  // the helper lies in x-z; the world's floor is x-y
    this.grid = grid;
    this.scene.add(grid, new THREE.AxesHelper(0.15));

    this.materials = {
      table: new THREE.MeshStandardMaterial({ color: 0xc9b89a, roughness: 0.9 }),
      link: new THREE.MeshStandardMaterial({ color: 0x8fa3bf, metalness: 0.2, roughness: 0.5 }),
      joint: new THREE.MeshStandardMaterial({ color: 0x2b3a55 }),
      tool: new THREE.MeshStandardMaterial({ color: 0x374151 }),
      dock: new THREE.MeshStandardMaterial({ color: 0xf59e0b, transparent: true, opacity: 0.55 }),
    };
    this.staticGroup = new THREE.Group();
    this.scene.add(this.staticGroup);
    // The world's origin, drawn with the links' material: the first frame compiles the shader
    // every later mesh uses, before any message has to wait for it.
    const origin = new THREE.Mesh(new THREE.CylinderGeometry(0.02, 0.02, 0.002, 16), this.materials.link);
    origin.rotation.x = Math.PI / 2;
    this.scene.add(origin);

    new ResizeObserver(() => this.resize()).observe(this.container);
    this.resize();
    this.statusNode.textContent = '';
    return true;
  }

  resize() {
    const width = Math.max(this.container.clientWidth, 1);
    const height = Math.max(this.container.clientHeight, 1);
    this.renderer.setSize(width, height, false);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    this.requestFrame();
  }

  // At most one frame per animation frame, and (software WebGL can take tens of ms a frame)
  // the 3D view never takes more than about a quarter of the page's main thread: the rest of
  // the page (skill states, the timeline) stays responsive while the robot moves.
  requestFrame() {
    if (this.frameScheduled) return;
    this.frameScheduled = true;
    const wait = Math.max(0, (this.nextFrameAt || 0) - performance.now());
    const draw = () => requestAnimationFrame(() => {
      this.frameScheduled = false;
      const started = performance.now();
      this.renderer.render(this.scene, this.camera);
      const took = performance.now() - started;
      this.nextFrameAt = performance.now() + Math.max(this.minFrameIntervalMs, 3 * took);
      this.resolveFirstFrame(took);
    });
    if (wait > 0) setTimeout(draw, wait);
    else draw();
  }

  // world: the merged state of `world` messages (see main.js).
  update(world) {
    this.world = world;
    if (!this.renderer) return;
    this.updateStatic(world);
    this.updateRobots(world);
    this.updateObjects(world);
    this.requestFrame();
  }

  updateStatic(world) {
    const key = JSON.stringify([world.tables, world.docks, world.tools]);
    if (key === this.staticKey) return;
    this.staticKey = key;
    for (const child of [...this.staticGroup.children]) this.staticGroup.remove(child);
    // The floor under the tables (or at z = 0 without any).
    let floor = 0;
    for (const table of Array.isArray(world.tables) ? world.tables.slice(0, 64) : []) {
      const top = Number(Array.isArray(table.pose) ? table.pose[2] : table.pose?.xyz?.[2]) || 0;
      floor = Math.min(floor, top - (Number(table.size?.[2]) || 0));
    }
    this.grid.position.z = floor - 0.001;
    for (const table of Array.isArray(world.tables) ? world.tables.slice(0, 64) : []) {
      const size = (table.size || [1, 0.8, 0.75]).map((v) => Math.max(Number(v) || 0.01, 0.001));
      const frame = new THREE.Group();
      setPose(frame, table.pose);
      const box = new THREE.Mesh(new THREE.BoxGeometry(size[0], size[1], size[2]), this.materials.table);
      box.position.z = -size[2] / 2;  // the pose is the centre of the top face
      frame.add(box);
      this.staticGroup.add(frame);
    }
    for (const dock of Array.isArray(world.docks) ? world.docks.slice(0, 64) : []) {
      if (!dock || !dock.pose) continue;  // a dock without a pose cannot be placed
      const frame = new THREE.Group();
      setPose(frame, dock.pose);
      const marker = new THREE.Mesh(new THREE.BoxGeometry(0.09, 0.09, 0.01), this.materials.dock);
      frame.add(marker);
      if (dock.tool) frame.add(toolMesh(this.toolLength(dock.tool), this.materials.tool));
      this.staticGroup.add(frame);
    }
  }

  toolLength(name) {
    const tool = (Array.isArray(this.world?.tools) ? this.world.tools : []).find((t) => t.name === name);
    const tcp = tool?.tcp;
    const z = Array.isArray(tcp) ? Number(tcp[2]) : Number(tcp?.xyz?.[2]);
    return Number.isFinite(z) && z > 0.02 && z < 2 ? z : kDefaultToolLength;
  }

  // The world's `models: {robot: model|null}` (or `robots: [{name, model, base}]`). Without
  // one, as docs/dashboard.md suggests, a model of GET /api/robots that is the robot's own
  // name (the thesis cell's robot "ur5" is a UR5); the page says that it guessed.
  robotModelName(name) {
    const model = this.world?.models?.[name];
    if (typeof model === 'string' && model) return model;
    const robots = this.world?.robots;
    if (Array.isArray(robots)) {
      const entry = robots.find((r) => r.name === name);
      if (entry?.model) return entry.model;
    } else if (robots && typeof robots === 'object' && robots[name]?.model) {
      return robots[name].model;
    }
    return this.modelByName(name);
  }

  modelByName(name) {
    if (this.knownModels === null) {
      this.knownModels = 'loading';
      this.fetchRobotModels().then((list) => {
        this.knownModels = Array.isArray(list) ? list.map(String).slice(0, 100) : [];
        if (this.world) this.update(this.world);
      }, () => { this.knownModels = []; });
    }
    if (!Array.isArray(this.knownModels)) return undefined;
    const match = this.knownModels.find((m) => m.toLowerCase() === String(name).toLowerCase());
    if (match) this.guessedModels.add(name);
    return match;
  }

  robotBase(name) {
    const base = this.world?.bases?.[name];
    if (base) return base;
    const robots = this.world?.robots;
    if (Array.isArray(robots)) return robots.find((r) => r.name === name)?.base;
    if (robots && typeof robots === 'object') return robots[name]?.base;
    return undefined;
  }

  model(modelName) {
    if (!modelName) return null;
    const known = this.models.get(modelName);
    if (Array.isArray(known)) return known;
    if (known) return null;  // loading or failed
    this.models.set(modelName, 'loading');
    this.fetchRobotModel(modelName).then((model) => {
      const rows = dhRows(model);
      this.models.set(modelName, rows || 'failed');
      if (this.world) this.update(this.world);
    }, () => {
      this.models.set(modelName, 'failed');
      if (this.world) this.update(this.world);
    });
    return null;
  }

  updateRobots(world) {
    const joints = world.joints && typeof world.joints === 'object' ? world.joints : {};
    const names = new Set(Object.keys(joints).slice(0, kMaxRobots));
    for (const [name, robot] of this.robots) {
      if (!names.has(name)) {
        this.scene.remove(robot.group);
        this.robots.delete(name);
      }
    }
    const notes = [];
    for (const name of names) {
      const modelName = this.robotModelName(name);
      const rows = this.model(modelName);
      if (!rows) {
        const state = this.models.get(modelName);
        notes.push(!modelName ? `robot ${name}: the server names no model, not drawn`
                   : state === 'failed' ? `robot ${name}: model ${modelName} unavailable`
                   : `robot ${name}: loading model ${modelName}`);
        continue;
      }
      let robot = this.robots.get(name);
      if (!robot || robot.rows !== rows) {
        if (robot) this.scene.remove(robot.group);
        robot = this.buildRobot(rows);
        this.robots.set(name, robot);
        this.scene.add(robot.group);
      }
      setPose(robot.group, this.robotBase(name));
      this.pose(robot, joints[name], world.tool?.[name] ?? null);
    }
    for (const name of names) {
      if (this.guessedModels.has(name) && this.robots.has(name)) {
        notes.push(`robot ${name}: model taken from its name (the world names none)`);
      }
    }
    const text = notes.join('; ');
    if (this.statusNode.textContent !== text) this.statusNode.textContent = text;
  }

  buildRobot(rows) {
    const group = new THREE.Group();
    const segments = [];
    for (let i = 0; i < rows.length * 2; ++i) segments.push(new Segment(group, 0.032, this.materials.link));
    const joints = rows.map(() => {
      const sphere = new THREE.Mesh(new THREE.SphereGeometry(0.045, 16, 12), this.materials.joint);
      group.add(sphere);
      return sphere;
    });
    const flange = new THREE.Group();
    flange.matrixAutoUpdate = false;
    group.add(flange);
    return { rows, group, segments, joints, flange, toolName: null, toolObject: null };
  }

  // Forward kinematics in the robot's base frame, one DH row at a time:
  // T(i-1 -> i) = Rz(q + thetaOffset) · Tz(d) · Tx(a) · Rx(alpha).
  pose(robot, q, toolName) {
    const frame = new THREE.Matrix4();
    const step = new THREE.Matrix4();
    const origin = new THREE.Vector3();
    robot.rows.forEach((row, i) => {
      const angle = (Array.isArray(q) && Number.isFinite(Number(q[i])) ? Number(q[i]) : 0) + row.thetaOffset;
      const start = origin.clone().setFromMatrixPosition(frame);
      robot.joints[i].position.copy(start);
      frame.multiply(step.makeRotationZ(angle)).multiply(step.makeTranslation(0, 0, row.d));
      const middle = new THREE.Vector3().setFromMatrixPosition(frame);
      frame.multiply(step.makeTranslation(row.a, 0, 0)).multiply(step.makeRotationX(row.alpha));
      const end = new THREE.Vector3().setFromMatrixPosition(frame);
      robot.segments[2 * i].set(start, middle);
      robot.segments[2 * i + 1].set(middle, end);
    });
    robot.flange.matrix.copy(frame);
    robot.flange.matrixWorldNeedsUpdate = true;
    if (robot.toolName !== toolName) {
      if (robot.toolObject) robot.flange.remove(robot.toolObject);
      robot.toolObject = toolName ? toolMesh(this.toolLength(toolName), this.materials.tool) : null;
      if (robot.toolObject) robot.flange.add(robot.toolObject);
      robot.toolName = toolName;
    }
  }

  updateObjects(world) {
    const objects = Array.isArray(world.objects) ? world.objects.slice(0, kMaxObjects) : [];
    const seen = new Set();
    for (const object of objects) {
      if (!object || typeof object.name !== 'string') continue;
      seen.add(object.name);
      let mesh = this.objects.get(object.name);
      if (!mesh) {
        const size = (Array.isArray(object.size) ? object.size : kDefaultObjectSize)
                         .map((v) => Math.min(Math.max(Number(v) || 0.04, 0.001), 10));
        let color = 0xe07b39;
        try {
          if (object.color) color = new THREE.Color().setStyle(String(object.color)).getHex();
        } catch { /* an unknown colour name keeps the default */ }
        mesh = new THREE.Mesh(new THREE.BoxGeometry(size[0], size[1], size[2]),
                              new THREE.MeshStandardMaterial({ color }));
        this.objects.set(object.name, mesh);
        this.scene.add(mesh);
      }
      mesh.visible = Boolean(object.pose);  // a pose not read yet: not drawn at the origin
      if (object.pose) setPose(mesh, object.pose);
    }
    for (const [name, mesh] of this.objects) {
      if (!seen.has(name)) {
        this.scene.remove(mesh);
        this.objects.delete(name);
      }
    }
  }
}
