#!/usr/bin/env node
// A stand-in for `pnp dashboard` (src/dashboard): serves the built page (the asset folder of
// web/CMakeLists.txt) and speaks the page's WebSocket protocol (docs/dashboard.md) with a
// synthetic cell, so the page and the browser test harness can be tested without the C++
// backend, and the page can be loaded with a large synthetic cell (--components 50
// --skills-per-component 10) for the responsiveness check. Node.js only, no dependencies.
//
//   node fake_dashboard_server.js --assets BUILD/web/dashboard [--port 0] [--host 127.0.0.1]
//        [--components N] [--skills-per-component M] [--burst-hz H] [--world-hz 30]
//        [--lifetime-s S] [--world-without-model]
// Prints one JSON line {"url": "http://HOST:PORT/"} once listening. Test hooks (loopback):
//   POST /fake/remove-component?name=NAME   the component's server and skills go away
//   POST /fake/add-component?name=NAME      a component appears (skills detected)
'use strict';

const crypto = require('node:crypto');
const fs = require('node:fs');
const http = require('node:http');
const path = require('node:path');

// ----- options ------------------------------------------------------------------------------
function parseOptions(argv) {
  const options = {
    assets: '', port: 0, host: '127.0.0.1', components: 0, skillsPerComponent: 4, burstHz: 0,
    worldHz: 30, lifetimeS: 3600, worldWithoutModel: false,
  };
  const numeric = { '--port': 'port', '--components': 'components',
                    '--skills-per-component': 'skillsPerComponent', '--burst-hz': 'burstHz',
                    '--world-hz': 'worldHz', '--lifetime-s': 'lifetimeS' };
  for (let i = 2; i < argv.length; ++i) {
    const arg = argv[i];
    const value = argv[i + 1];
    if (arg === '--assets') { options.assets = value; ++i; }
    // As the simulator's ground truth today: the robot's model is not named (models null);
    // the robot is called like its model, so the page can take the model from its name.
    else if (arg === '--world-without-model') options.worldWithoutModel = true;
    else if (arg === '--host') { options.host = value; ++i; }
    else if (numeric[arg]) {
      const number = Number(value);
      if (!Number.isFinite(number) || number < 0) throw new Error(`${arg}: not a number: ${value}`);
      options[numeric[arg]] = number;
      ++i;
    } else throw new Error(`unknown argument ${arg}`);
  }
  if (!options.assets) throw new Error('--assets DIR is required');
  options.components = Math.min(options.components, 1000);
  options.skillsPerComponent = Math.min(Math.max(options.skillsPerComponent, 1), 100);
  options.burstHz = Math.min(options.burstHz, 5000);
  options.worldHz = Math.min(Math.max(options.worldHz, 1), 30);
  return options;
}

// ----- the synthetic cell -------------------------------------------------------------------
const kLdsUrl = 'opc.tcp://127.0.0.1:4840';
const kTimelineLength = 200;

// Synthetic 6-axis arm (not any vendor's), in the answer's shape of GET /api/robot/<model>
// (src/dashboard/robot_description.hpp): only for drawing the fake cell.
const kSyntheticArm = {
  model: 'synthetic-arm',
  convention: 'standard DH: Rz(q+theta)·Tz(d)·Tx(a)·Rx(alpha)',
  dh: [
    { a: 0, d: 0.09, alpha: Math.PI / 2, theta: 0 },
    { a: -0.42, d: 0, alpha: 0, theta: 0 },
    { a: -0.39, d: 0, alpha: 0, theta: 0 },
    { a: 0, d: 0.11, alpha: Math.PI / 2, theta: 0 },
    { a: 0, d: 0.095, alpha: -Math.PI / 2, theta: 0 },
    { a: 0, d: 0.08, alpha: 0, theta: 0 },
  ],
  limits: Array.from({ length: 6 }, () => ({ min: -2 * Math.PI, max: 2 * Math.PI })),
};

const kSkillTemplates = [
  { name: 'MoveJoints', type: 'JointPtpMoveSkillType', durationMs: 600, moves: true,
    parameters: [{ name: 'TargetJoints', dataType: 'Double[]', valueRank: 1 },
                 { name: 'MaxVelocity', dataType: 'Double', valueRank: -1 }] },
  { name: 'Grasp', type: 'GraspSkillType', durationMs: 250,
    parameters: [{ name: 'Force', dataType: 'Double', valueRank: -1 }] },
  { name: 'Release', type: 'ReleaseSkillType', durationMs: 150, parameters: [] },
  { name: 'Delay', type: 'DelaySkillType', durationMs: 200,
    parameters: [{ name: 'DurationMs', dataType: 'UInt32', valueRank: -1 }] },
  { name: 'ChangeTool', type: 'ChangeToolSkillType', durationMs: 800, moves: true,
    parameters: [{ name: 'Tool', dataType: 'String', valueRank: -1 }] },
  { name: 'PickAndPlace', type: 'PickAndPlaceSkillType', durationMs: 900, moves: true,
    parameters: [{ name: 'ObjectId', dataType: 'String', valueRank: -1 },
                 { name: 'PlacePosition', dataType: 'Double[]', valueRank: 1 }] },
];

const kBaseComponents = [
  { name: 'robot', skills: ['MoveJoints', 'Delay'] },
  { name: 'gripper', skills: ['Grasp', 'Release'] },
  { name: 'toolchanger', skills: ['ChangeTool'] },
  { name: 'pickplace', skills: ['PickAndPlace'] },
  { name: 'mes', skills: ['ExecuteProcess'] },
];

class Cell {
  constructor(options, broadcast) {
    this.broadcast = broadcast;
    this.robot = options.worldWithoutModel ? kSyntheticArm.model : 'arm';
    this.robotModel = options.worldWithoutModel ? null : kSyntheticArm.model;
    this.servers = new Map();
    this.components = new Map();
    this.skills = new Map();
    this.timeline = [];
    this.detectionMs = [];
    this.process = null;
    this.durations = {};  // skill type -> [ms]
    this.joints = [0, -1.57, 1.57, -1.57, -1.57, 0];
    this.movingUntil = 0;
    this.objects = [{ name: 'cube-green', size: [0.04, 0.04, 0.04], color: 'green',
                      pose: [0.05, 0.1, 0.02, 0, 0, 0], holder: null }];
    this.servers.set(kLdsUrl, { url: kLdsUrl, applicationUri: 'urn:fake:lds', name: 'LDS-ME',
                                capabilities: ['LDS'], parent: null });
    for (const component of kBaseComponents) this.addComponent(component.name, component.skills, false);
    const extraSkills = kSkillTemplates.map((t) => t.name);
    for (let i = 0; i < options.components; ++i) {
      const names = [];
      for (let k = 0; k < options.skillsPerComponent; ++k) names.push(extraSkills[k % extraSkills.length]);
      this.addComponent(`device-${String(i).padStart(3, '0')}`, names, false);
    }
  }

  addComponent(name, skillNames, announce = true) {
    if (this.components.has(name)) return;
    const port = 4841 + this.servers.size;
    const url = `opc.tcp://127.0.0.1:${port}`;
    const server = { url, applicationUri: `urn:fake:${name}`, name, capabilities: [], parent: kLdsUrl };
    // The shapes of src/dashboard/cell_view.cpp: a component is keyed by its id.
    const component = { id: `${url}#${name}`, name, endpoint: url, applicationUri: `urn:fake:${name}`,
                        applicationName: `fake ${name}` };
    this.servers.set(url, server);
    this.components.set(name, component);
    if (announce) {
      this.broadcast({ type: 'server', op: 'add', server });
      this.broadcast({ type: 'component', op: 'add', component });
    }
    const detectionMs = 150 + Math.round(Math.random() * 200);
    this.detectionMs.push(detectionMs);
    if (this.detectionMs.length > 200) this.detectionMs.shift();
    skillNames.forEach((skillName, index) => {
      const template = skillName === 'ExecuteProcess'
          ? { name: 'ExecuteProcess', type: 'ExecuteProcessSkillType', durationMs: 0,
              parameters: [{ name: 'ProcessIri', dataType: 'String', valueRank: -1 }] }
          : kSkillTemplates.find((t) => t.name === skillName);
      const instance = skillNames.indexOf(skillName) === index ? skillName : `${skillName}${index}`;
      const skill = {
        id: `${name}/${instance}`, component: name, componentId: component.id,
        componentUri: component.applicationUri, componentName: component.applicationName, endpoint: url,
        name: instance, type: template.type, types: [template.type, 'SkillType'],
        parameters: template.parameters, state: 'Ready', lastResult: null,
      };
      Object.defineProperty(skill, 'runtime', { value: { template, timer: null, remainingMs: 0, startedAt: 0, runStartMs: 0 },
                                                 enumerable: false });
      this.skills.set(skill.id, skill);
      if (announce) this.broadcast({ type: 'skill', op: 'add', skill: { ...skill, detectionMs } });
    });
  }

  removeComponent(name) {
    const component = this.components.get(name);
    if (!component) return false;
    for (const skill of [...this.skills.values()]) {
      if (skill.component !== name) continue;
      clearTimeout(skill.runtime.timer);
      this.skills.delete(skill.id);
      this.broadcast({ type: 'skill', op: 'remove', skill: { id: skill.id } });
    }
    this.components.delete(name);
    this.broadcast({ type: 'component', op: 'remove', component: { id: component.id } });
    this.servers.delete(component.endpoint);
    this.broadcast({ type: 'server', op: 'remove', server: { url: component.endpoint } });
    return true;
  }

  snapshot() {
    return {
      type: 'snapshot',
      servers: [...this.servers.values()],
      components: [...this.components.values()],
      skills: [...this.skills.values()],
      process: this.process,
      world: this.world(true),
      timeline: this.timeline,
      stats: { detectionMs: this.detectionMs, skillDurations: this.durations },
    };
  }

  // The backend's world message (joints, tool, models, objects, tools, docks, time) plus
  // static items it does not send yet (bases, tables, dock poses, object sizes and colours,
  // tool TCPs): the page draws them when present.
  world(full) {
    const update = {
      joints: { [this.robot]: this.joints }, tool: { [this.robot]: 'parallel-gripper' }, objects: this.objects,
      time: Date.now(),
    };
    if (!full) return update;
    return {
      ...update,
      models: { [this.robot]: this.robotModel },
      bases: { [this.robot]: [-0.3, 0, 0, 0, 0, 0] },
      tables: [{ name: 'table', pose: [0, 0, 0, 0, 0, 0], size: [1.0, 0.8, 0.75] }],
      tools: [{ name: 'parallel-gripper', dock: null, robot: this.robot, tcp: [0, 0, 0.2, 0, 0, 0] },
              { name: 'vacuum-gripper', dock: 'dock-1', robot: null, tcp: [0, 0, 0.19, 0, 0, 0] }],
      docks: [{ name: 'dock-1', pose: [-0.125, 0.513, -0.036, 0, Math.PI, 0], tool: 'vacuum-gripper' },
              { name: 'dock-2', pose: [0.125, 0.513, -0.036, 0, Math.PI, 0], tool: null }],
    };
  }

  // As the backend: the transition at once (no result in it); when a run ended, the result
  // follows in a re-announced `skill` (its FinalResultData read) and the durations in `stats`.
  transition(skill, to, { result, message } = {}) {
    const time = Date.now();
    const event = { type: 'transition', skill: skill.id, from: skill.state, to, transition: `${skill.state}To${to}`, time };
    if (message) event.message = message;
    if (to === 'Running' && skill.state === 'Ready') skill.runtime.runStartMs = time;
    skill.state = to;
    const { type, ...stored } = event;
    this.timeline.push(stored);
    if (this.timeline.length > kTimelineLength) this.timeline.shift();
    this.broadcast(event);
    if (result) {
      skill.lastResult = { result, message: message || '', values: {}, time };
      if (skill.runtime.runStartMs) {
        const list = (this.durations[skill.type] ||= []);
        list.push(time - skill.runtime.runStartMs);
        if (list.length > 200) list.shift();
        skill.runtime.runStartMs = 0;
        this.broadcast({ type: 'stats', detectionMs: this.detectionMs, skillDurations: this.durations });
      }
      setTimeout(() => {
        if (this.skills.get(skill.id) === skill) this.broadcast({ type: 'skill', op: 'add', skill });
      }, 5);
    }
  }

  // ----- actions: {ok, status, message} like the real backend's replies -----
  act(request, session) {
    const fail = (status, message) => ({ ok: false, status, message });
    switch (request.action) {
      case 'logout':
        session.user = null;
        return { ok: true, status: 'Good', message: 'anonymous' };
      case 'login':
        if (!request.user) { session.user = null; return { ok: true, status: 'Good', message: 'anonymous' }; }
        if (request.user === 'operator' && request.password === 'operator') {
          session.user = request.user;
          return { ok: true, status: 'Good', message: `logged in as ${request.user}` };
        }
        return fail('BadUserAccessDenied', 'user name or password rejected by the server');
      case 'run': return this.run(request);
      case 'halt': case 'suspend': case 'resume': case 'reset': return this.control(request);
      case 'startProcess': return this.startProcess(request);
      default: return fail('BadNotSupported', `unknown action '${request.action}'`);
    }
  }

  run(request) {
    const skill = this.skills.get(String(request.skill));
    if (!skill) return { ok: false, status: 'BadNodeIdUnknown', message: `no skill ${request.skill}` };
    const parameters = request.parameters && typeof request.parameters === 'object' ? request.parameters : {};
    for (const [name, text] of Object.entries(parameters)) {
      const declared = skill.parameters.find((p) => p.name === name);
      if (!declared) return { ok: false, status: 'BadNotFound', message: `${skill.name} has no parameter ${name}` };
      const error = convert(String(text), declared);
      if (error) return { ok: false, status: 'BadTypeMismatch', message: `${name}: ${error}` };
    }
    if (skill.state !== 'Ready') {
      return { ok: false, status: 'BadInvalidState', message: `${skill.name} is ${skill.state}, not Ready` };
    }
    let durationMs = skill.runtime.template.durationMs;
    if (parameters.DurationMs !== undefined) durationMs = Number(parameters.DurationMs);
    this.start(skill, durationMs);
    return { ok: true, status: 'Good', message: 'started' };
  }

  start(skill, durationMs) {
    this.transition(skill, 'Running');
    skill.runtime.remainingMs = durationMs;
    this.resumeTimer(skill);
  }

  resumeTimer(skill) {
    skill.runtime.startedAt = Date.now();
    if (skill.runtime.template.moves) this.movingUntil = Math.max(this.movingUntil, Date.now() + skill.runtime.remainingMs);
    skill.runtime.timer = setTimeout(() => {
      skill.runtime.timer = null;
      if (skill.state === 'Running') this.transition(skill, 'Ready', { result: 'Completed' });
    }, skill.runtime.remainingMs);
  }

  control(request) {
    const skill = this.skills.get(String(request.skill));
    if (!skill) return { ok: false, status: 'BadNodeIdUnknown', message: `no skill ${request.skill}` };
    const bad = () => ({ ok: false, status: 'BadInvalidState', message: `${request.action} not allowed in ${skill.state}` });
    const stopTimer = () => {
      clearTimeout(skill.runtime.timer);
      skill.runtime.timer = null;
      skill.runtime.remainingMs = Math.max(0, skill.runtime.remainingMs - (Date.now() - skill.runtime.startedAt));
    };
    switch (request.action) {
      case 'halt':
        if (skill.state === 'Halted') return bad();
        stopTimer();
        this.transition(skill, 'Halted', { result: 'Aborted', message: 'halted by the operator' });
        break;
      case 'suspend':
        if (skill.state !== 'Running') return bad();
        stopTimer();
        this.transition(skill, 'Suspended');
        break;
      case 'resume':
        if (skill.state !== 'Suspended') return bad();
        this.transition(skill, 'Running');
        this.resumeTimer(skill);
        break;
      case 'reset':
        if (skill.state !== 'Halted') return bad();
        this.transition(skill, 'Ready');
        break;
      default: return bad();
    }
    return { ok: true, status: 'Good', message: '' };
  }

  startProcess(request) {
    if (typeof request.processIri !== 'string' || !/^[a-z][a-z0-9+.-]*:/i.test(request.processIri)) {
      return { ok: false, status: 'BadInvalidArgument', message: 'ProcessIri must be an IRI' };
    }
    if (this.process && this.process.state === 'Running') {
      return { ok: false, status: 'BadInvalidState', message: 'a process is already running' };
    }
    const plan = ['robot/MoveJoints', 'gripper/Grasp', 'robot/MoveJoints', 'gripper/Release']
        .map((id) => this.skills.get(id)).filter(Boolean);
    if (!plan.length) return { ok: false, status: 'BadNotFound', message: 'no skill for the process' };
    const execution = crypto.randomUUID();
    this.process = {
      type: 'process', execution, processIri: request.processIri, state: 'Running', running: 0,
      steps: plan.map((skill, index) => ({ index, label: `${skill.name} ${index}`, skillType: skill.type,
                                           component: skill.component, result: null, durationS: null })),
    };
    this.broadcast(this.process);
    const runStep = (index) => {
      if (index >= plan.length) {
        Object.assign(this.process, { state: 'Ready', running: null, activeSkill: null, result: 'Completed' });
        this.broadcast(this.process);
        return;
      }
      const skill = plan[index];
      if (skill.state !== 'Ready') {
        Object.assign(this.process, { state: 'Halted', running: null, activeSkill: null, result: 'Failed',
                                      reason: `${skill.id} is ${skill.state}` });
        this.broadcast(this.process);
        return;
      }
      this.process.running = index;
      this.process.activeSkill = skill.id;
      this.broadcast(this.process);
      const started = Date.now();
      this.start(skill, skill.runtime.template.durationMs);
      setTimeout(() => {
        Object.assign(this.process.steps[index], { result: 'Completed', durationS: (Date.now() - started) / 1000 });
        runStep(index + 1);
      }, skill.runtime.template.durationMs + 20);
    };
    setTimeout(() => runStep(0), 10);
    return { ok: true, status: 'Good', message: `execution ${execution}` };
  }

  // While a moving skill runs, the joints move (a world message at worldHz).
  tickWorld() {
    if (Date.now() > this.movingUntil) return;
    const t = Date.now() / 1000;
    this.joints = [0.6 * Math.sin(t), -1.57 + 0.3 * Math.sin(1.3 * t), 1.57 + 0.3 * Math.cos(t),
                   -1.57, -1.57, 0.5 * Math.sin(2 * t)];
    this.broadcast({ type: 'world', ...this.world(false) });
  }

  // Synthetic load: each tick one Ready skill starts (completes after its template's time).
  tickBurst() {
    const ready = [...this.skills.values()].filter((s) => s.state === 'Ready' && s.component.startsWith('device-'));
    if (!ready.length) return;
    const skill = ready[Math.floor(Math.random() * ready.length)];
    this.start(skill, 50 + Math.random() * 300);
  }
}

function convert(text, parameter) {
  const type = String(parameter.dataType).replace(/\[\]$/, '');  // docs/dashboard.md: "Double[]"
  const scalar = (value) => {
    switch (type) {
      case 'Double': case 'Float': return Number.isFinite(Number(value)) && String(value).trim() !== '' ? null : `'${value}' is not a ${type}`;
      case 'UInt32': return /^\d{1,10}$/.test(String(value).trim()) && Number(value) <= 4294967295 ? null : `'${value}' is not a UInt32`;
      case 'Boolean': return /^(true|false)$/.test(String(value)) ? null : `'${value}' is not a Boolean`;
      default: return null;
    }
  };
  if (parameter.valueRank >= 1) {
    let list;
    try { list = JSON.parse(text); } catch { return `'${text.slice(0, 40)}' is not an array`; }
    if (!Array.isArray(list)) return `'${text.slice(0, 40)}' is not an array`;
    for (const item of list) { const error = scalar(item); if (error) return error; }
    return null;
  }
  return scalar(text);
}

// ----- WebSocket (RFC 6455, server side: the few frames a browser sends) ---------------------
const kWebSocketGuid = '258EAFA5-E914-47DA-95CA-C5AB0DC85B11';
const kMaxFrameIn = 64 * 1024;
const kMaxQueuedOut = 8 * 1024 * 1024;

function frame(opcode, payload) {
  const length = payload.length;
  let header;
  if (length < 126) header = Buffer.from([0x80 | opcode, length]);
  else if (length < 65536) { header = Buffer.alloc(4); header[0] = 0x80 | opcode; header[1] = 126; header.writeUInt16BE(length, 2); }
  else { header = Buffer.alloc(10); header[0] = 0x80 | opcode; header[1] = 127; header.writeBigUInt64BE(BigInt(length), 2); }
  return Buffer.concat([header, payload]);
}

class WebSocketClient {
  constructor(socket, onText, onClose) {
    this.socket = socket;
    this.onText = onText;
    this.onClose = onClose;
    this.buffer = Buffer.alloc(0);
    this.closed = false;
    socket.setNoDelay(true);
    socket.on('data', (chunk) => this.receive(chunk));
    socket.on('close', () => this.finish());
    socket.on('error', () => this.finish());
  }

  receive(chunk) {
    this.buffer = Buffer.concat([this.buffer, chunk]);
    for (;;) {
      if (this.buffer.length < 2) return;
      const opcode = this.buffer[0] & 0x0f;
      const masked = (this.buffer[1] & 0x80) !== 0;
      let length = this.buffer[1] & 0x7f;
      let offset = 2;
      if (length === 126) { if (this.buffer.length < 4) return; length = this.buffer.readUInt16BE(2); offset = 4; }
      else if (length === 127) { if (this.buffer.length < 10) return; length = Number(this.buffer.readBigUInt64BE(2)); offset = 10; }
      if (length > kMaxFrameIn || !masked) { this.close(1009); return; }
      if (this.buffer.length < offset + 4 + length) return;
      const mask = this.buffer.subarray(offset, offset + 4);
      const payload = Buffer.from(this.buffer.subarray(offset + 4, offset + 4 + length));
      for (let i = 0; i < payload.length; ++i) payload[i] ^= mask[i & 3];
      this.buffer = this.buffer.subarray(offset + 4 + length);
      if (opcode === 0x1) this.onText(payload.toString('utf8'));
      else if (opcode === 0x8) { this.close(1000); return; }
      else if (opcode === 0x9) this.write(frame(0xA, payload));
    }
  }

  send(text) { this.write(frame(0x1, Buffer.from(text, 'utf8'))); }

  write(data) {
    if (this.closed) return;
    // A page that does not read is dropped rather than queued without bound.
    if (this.socket.writableLength > kMaxQueuedOut) { this.close(1008); return; }
    this.socket.write(data);
  }

  close(code) {
    if (this.closed) return;
    const payload = Buffer.alloc(2);
    payload.writeUInt16BE(code, 0);
    this.socket.write(frame(0x8, payload));
    this.socket.end();
    this.finish();
  }

  finish() {
    if (this.closed) return;
    this.closed = true;
    this.socket.destroy();
    this.onClose();
  }
}

// ----- HTTP ---------------------------------------------------------------------------------
const kContentTypes = {
  '.html': 'text/html; charset=utf-8', '.js': 'text/javascript; charset=utf-8',
  '.css': 'text/css; charset=utf-8', '.json': 'application/json', '.png': 'image/png',
  '.svg': 'image/svg+xml', '': 'text/plain; charset=utf-8',
};

function main() {
  const options = parseOptions(process.argv);
  const assetRoot = path.resolve(options.assets);
  const clients = new Set();
  const broadcast = (message) => {
    const text = JSON.stringify(message);
    for (const client of clients) client.send(text);
  };
  const cell = new Cell(options, broadcast);

  const server = http.createServer((request, response) => {
    const url = new URL(request.url, 'http://localhost');
    const reply = (status, type, body) => {
      response.writeHead(status, { 'Content-Type': type, 'Cache-Control': 'no-store' });
      response.end(body);
    };
    if (url.pathname === '/api/snapshot') return reply(200, 'application/json', JSON.stringify(cell.snapshot()));
    if (url.pathname === '/api/robots') return reply(200, 'application/json', JSON.stringify([kSyntheticArm.model]));
    if (url.pathname.startsWith('/api/robot/')) {
      const model = decodeURIComponent(url.pathname.slice('/api/robot/'.length));
      if (model === kSyntheticArm.model) return reply(200, 'application/json', JSON.stringify(kSyntheticArm));
      return reply(404, 'application/json', JSON.stringify({ error: `no robot model ${model}` }));
    }
    if (request.method === 'POST' && url.pathname === '/fake/remove-component') {
      const ok = cell.removeComponent(url.searchParams.get('name') || '');
      return reply(ok ? 200 : 404, 'application/json', JSON.stringify({ ok }));
    }
    if (request.method === 'POST' && url.pathname === '/fake/add-component') {
      cell.addComponent(url.searchParams.get('name') || 'added', ['Delay', 'Grasp']);
      return reply(200, 'application/json', JSON.stringify({ ok: true }));
    }
    if (request.method !== 'GET' || url.pathname.length > 512) return reply(400, kContentTypes[''], 'bad request');
    const relative = url.pathname === '/' ? 'index.html' : decodeURIComponent(url.pathname).replace(/^\/+/, '');
    const file = path.resolve(assetRoot, relative);
    if (!file.startsWith(assetRoot + path.sep)) return reply(403, kContentTypes[''], 'forbidden');
    fs.readFile(file, (error, data) => {
      if (error) return reply(404, kContentTypes[''], 'not found');
      reply(200, kContentTypes[path.extname(file)] || 'application/octet-stream', data);
    });
  });

  server.on('upgrade', (request, socket) => {
    const key = request.headers['sec-websocket-key'];
    if (new URL(request.url, 'http://localhost').pathname !== '/ws' || !key || clients.size >= 64) {
      socket.end('HTTP/1.1 400 Bad Request\r\n\r\n');
      return;
    }
    const accept = crypto.createHash('sha1').update(key + kWebSocketGuid).digest('base64');
    socket.write(`HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n` +
                 `Sec-WebSocket-Accept: ${accept}\r\n\r\n`);
    const session = { user: null };
    const client = new WebSocketClient(socket, (text) => {
      let requestMessage;
      try { requestMessage = JSON.parse(text); } catch { return client.send(JSON.stringify({ type: 'error', message: 'not JSON' })); }
      const answer = cell.act(requestMessage || {}, session);
      client.send(JSON.stringify({ type: 'reply', id: requestMessage?.id ?? null, ...answer }));
    }, () => clients.delete(client));
    client.send(JSON.stringify(cell.snapshot()));
    clients.add(client);
  });

  const timers = [setInterval(() => cell.tickWorld(), 1000 / options.worldHz)];
  if (options.burstHz > 0) timers.push(setInterval(() => cell.tickBurst(), 1000 / options.burstHz));
  const stop = () => {
    timers.forEach(clearInterval);
    for (const client of clients) client.close(1001);
    server.close();
    process.exit(0);
  };
  setTimeout(stop, options.lifetimeS * 1000).unref();
  process.on('SIGTERM', stop);
  process.on('SIGINT', stop);
  server.listen(options.port, options.host, () => {
    const { port } = server.address();
    process.stdout.write(`${JSON.stringify({ url: `http://${options.host}:${port}/` })}\n`);
  });
}

try {
  main();
} catch (error) {
  process.stderr.write(`fake_dashboard_server: ${error.message}\n`);
  process.exit(2);
}
