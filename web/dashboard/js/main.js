// The dashboard page: one WebSocket (docs/dashboard.md), a snapshot first, then small
// messages applied incrementally to the panels. Nothing here polls the server.
import { Connection } from './connection.js';
import { el, setText, clockText } from './dom.js';
import { NetworkPanel } from './network_panel.js';
import { ComponentsPanel } from './components_panel.js';
import { TimelinePanel } from './timeline_panel.js';
import { ProcessPanel } from './process_panel.js';
import { PlotsPanel } from './plots_panel.js';

const kMaxLatencySamples = 100000;
const kMaxErrorsShown = 6;
const kProcessSkillType = 'ExecuteProcessSkillType';

// Read by the browser test (tests/dashboard/browser/dashboard_test.js).
const dashboard = {
  ready: false,               // true once the first snapshot is shown
  settled: false,             // true once the 3D view drew its first frame (or has none)
  view3d: 'starting',         // 'shown' | 'absent' | 'off' | 'unavailable' | 'failed'
  snapshots: 0,
  messages: 0,
  transitionLatencies: [],    // per transition: Date.now() - msg.time after the page shows it
  errorsShown: 0,
};
window.pnpDashboard = dashboard;

const $ = (id) => document.getElementById(id);

// ----- errors and notices -------------------------------------------------------------------
const errorArea = $('errors');
function showError(text) {
  dashboard.errorsShown += 1;
  const entry = el('div', { class: 'error', 'data-error': '' },
                   el('span', { class: 'timeline-time', text: clockText(Date.now()) }),
                   el('span', { class: 'error-text', text }),
                   el('button', { type: 'button', text: '×', title: 'dismiss',
                                  onclick: () => { entry.remove(); errorArea.hidden = !errorArea.childElementCount; } }));
  errorArea.prepend(entry);
  while (errorArea.childElementCount > kMaxErrorsShown) errorArea.lastElementChild.remove();
  errorArea.hidden = false;
}
let noticeTimer = null;
function showNotice(text) {
  setText($('notice'), text);
  clearTimeout(noticeTimer);
  noticeTimer = setTimeout(() => setText($('notice'), ''), 5000);
}

// ----- panels -------------------------------------------------------------------------------
const network = new NetworkPanel($('network-tree'), $('network-empty'));
const components = new ComponentsPanel($('component-list'), $('components-empty'), $('component-count'),
                                       { onAction: (action, fields, skill) => runAction(action, fields, skill) });
const timeline = new TimelinePanel($('timeline'));
const processPanel = new ProcessPanel($('process-view'), (id) => skillLabel(id));
const plots = new PlotsPanel($('plot-durations'), $('plot-detection'));
let cellView = null;
let world = null;

function skillLabel(id) {
  const skill = components.skill(id);
  return skill ? `${skill.component || '?'} / ${skill.name || id}` : String(id);
}

// Durations measured from the transitions (Running entered → left for Ready or Halted), per type.
// Only while the server sends no durations of its own (`stats` messages).
const runningSince = new Map();  // skill id -> ms
let serverStats = false;
function trackDuration(message) {
  if (serverStats) return;
  const id = String(message.skill);
  if (message.to === 'Running' && message.from !== 'Suspended') runningSince.set(id, Number(message.time));
  if ((message.to === 'Ready' || message.to === 'Halted') && runningSince.has(id)) {
    const skill = components.skill(id);
    plots.addDuration(skill?.type || 'unknown', Number(message.time) - runningSince.get(id));
    runningSince.delete(id);
  }
}

// ----- world (3D) ---------------------------------------------------------------------------
// A `world` message carries what changed; the page keeps the merge (joints and tool per robot).
function mergeWorld(update) {
  if (!update || typeof update !== 'object') return;
  world = world || { joints: {}, tool: {} };
  for (const [key, value] of Object.entries(update)) {
    if ((key === 'joints' || key === 'tool') && value && typeof value === 'object') {
      world[key] = { ...world[key], ...value };
    } else if (key !== 'type') {
      world[key] = value;
    }
  }
  cellView?.update(world);
}

async function startCellView() {
  const started = performance.now();
  dashboard.view3d = await startCellViewSteps();
  dashboard.view3dStartMs = performance.now() - started;
  dashboard.settled = true;
}

async function startCellViewSteps() {
  const status = $('view3d-status');
  if (new URLSearchParams(window.location.search).get('view3d') === 'off') {
    status.textContent = '3D view off (?view3d=off)';
    return 'off';
  }
  let vendor;
  try {
    const response = await fetch('assets/vendor.json', { cache: 'no-cache' });
    vendor = response.ok ? await response.json() : { three: false };
  } catch {
    vendor = { three: false };
  }
  if (!vendor.three) {
    status.textContent = '3D view absent: this build has no three.js (run npm ci, then build again).';
    return 'absent';
  }
  try {
    const { CellView } = await import('./view3d.js');
    const view = new CellView($('view3d'), status, { fetchRobotModel, fetchRobotModels });
    if (!view.start()) return 'unavailable';
    cellView = view;
    if (world) cellView.update(world);
    await Promise.race([view.firstFrame, new Promise((resolve) => setTimeout(resolve, 20000))]);
    return 'shown';
  } catch (error) {
    status.textContent = `3D view failed to start: ${error.message || error}`;
    return 'failed';
  }
}

async function fetchJson(path) {
  const controller = new AbortController();
  const timer = setTimeout(() => controller.abort(), 10000);
  try {
    const response = await fetch(path, { signal: controller.signal });
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    return await response.json();
  } finally {
    clearTimeout(timer);
  }
}
const fetchRobotModel = (model) => fetchJson(`api/robot/${encodeURIComponent(model)}`);
const fetchRobotModels = () => fetchJson('api/robots');

// ----- messages -----------------------------------------------------------------------------
function applySnapshot(snapshot) {
  const started = performance.now();
  network.reset(snapshot.servers);
  components.reset(snapshot.components, snapshot.skills);
  timeline.reset(snapshot.timeline, skillLabel);
  processPanel.show(snapshot.process || null);
  plots.reset(snapshot.stats);
  serverStats = Boolean(snapshot.stats && typeof snapshot.stats.skillDurations === 'object');
  runningSince.clear();
  world = null;
  if (snapshot.world) mergeWorld(snapshot.world);
  dashboard.snapshots += 1;
  dashboard.snapshotApplyMs = performance.now() - started;
  if (!dashboard.ready) dashboard.readyAtMs = performance.now();
  dashboard.ready = true;
  document.body.dataset.ready = 'true';
}

function applyTransition(message) {
  const known = components.transition(message);
  timeline.add(message, skillLabel);
  trackDuration(message);
  // Measured after the DOM shows it (state cell and timeline row updated above).
  const time = Number(message.time);
  if (known && Number.isFinite(time) && dashboard.transitionLatencies.length < kMaxLatencySamples) {
    dashboard.transitionLatencies.push(Date.now() - time);
  }
}

const handlers = {
  snapshot: applySnapshot,
  server: (m) => (m.op === 'remove' ? network.remove(m.server?.url ?? m.url) : network.add(m.server)),
  component: (m) => (m.op === 'remove'
      ? components.removeComponent(m.component?.id ?? m.component?.uri ?? m.component?.name ?? m.id)
      : components.addComponent(m.component)),
  skill: (m) => {
    if (m.op === 'remove') {
      components.removeSkill(m.skill?.id ?? m.id);
      return;
    }
    components.addSkill(m.skill);
    if (Number.isFinite(Number(m.skill?.detectionMs))) plots.addDetection(Number(m.skill.detectionMs));
  },
  transition: applyTransition,
  process: (m) => processPanel.show(m),
  world: mergeWorld,
  stats: (m) => {
    serverStats = serverStats || Boolean(m.skillDurations);
    plots.merge(m);
  },
  reply: (m) => {
    if (!m.ok) showError(`${m.label ? `${m.label}: ` : ''}${m.status || 'error'}: ${m.message || 'the action failed'}`);
  },
  error: (m) => showError(`server: ${m.message || m.status || 'error'}`),
};

function onMessage(message) {
  dashboard.messages += 1;
  const handler = handlers[message.type];
  if (!handler) return;  // newer server, older page: unknown types are skipped
  if (!dashboard.ready && message.type !== 'snapshot' && message.type !== 'reply') return;
  try {
    handler(message);
  } catch (error) {
    // A malformed message must not stop the page; it is reported once per message.
    console.warn(`dashboard: could not apply a ${message.type} message:`, error);
  }
}

// ----- actions ------------------------------------------------------------------------------
let connection = null;
async function runAction(action, fields, skill) {
  const what = skill ? `${action} ${skill.component || ''}/${skill.name || fields.skill}` : action;
  showNotice(`${what}…`);
  const reply = await connection.request(action, fields, what);
  // Server replies with ok=false are shown by the `reply` handler; local failures here.
  if (!reply.ok && reply.local) showError(`${what}: ${reply.status}: ${reply.message}`);
  showNotice(reply.ok ? `${what}: ${reply.status || 'Good'}${reply.message ? ` — ${reply.message}` : ''}` : '');
  return reply;
}

$('login').addEventListener('submit', async (event) => {
  event.preventDefault();
  const user = $('login-user').value;
  const password = $('login-password').value;
  const reply = await runAction('login', { user, password });
  $('login-password').value = '';
  if (reply.ok) showUser(user);
});

function showUser(user) {
  setText($('login-status'), user ? `logged in as ${user}` : 'anonymous');
  $('logout').hidden = !user;
}

$('logout').addEventListener('click', async () => {
  const reply = await runAction('logout', { user: '', password: '' });
  if (reply.ok) showUser('');
});

$('process-start').addEventListener('submit', (event) => {
  event.preventDefault();
  const processIri = $('process-iri').value.trim();
  if (!processIri) return;
  const fields = { processIri };
  // The MES to ask: the first ExecuteProcess skill the page knows (the server may choose).
  for (const entry of components.skills.values()) {
    const types = [entry.skill.type, ...(entry.skill.types || [])].map(String);
    if (types.some((t) => t.endsWith(kProcessSkillType))) {
      fields.skill = String(entry.skill.id);
      break;
    }
  }
  runAction('startProcess', fields);
});

// ----- connection ---------------------------------------------------------------------------
function connectionState(state, detail) {
  const node = $('connection');
  node.dataset.state = state;
  setText(node, state === 'open' ? 'live' : state === 'connecting' ? 'connecting…' : `offline: ${detail || ''}`);
}

const wsUrl = new URL('ws', window.location.href);
wsUrl.protocol = window.location.protocol === 'https:' ? 'wss:' : 'ws:';
connection = new Connection(wsUrl.href, { onMessage, onStateChange: connectionState });
connection.start();
startCellView();
