// The page's one WebSocket to the dashboard server (docs/dashboard.md): messages in, actions
// out. Reconnects with exponential backoff when the socket closes; every action has an id
// and a deadline, and is answered by the server's `reply` (or fails locally on timeout or
// when the connection drops).

const kBackoffFirstMs = 250;
const kBackoffMaxMs = 5000;
const kActionTimeoutMs = 30000;
// `run` and `startProcess` are answered when the run ends (docs/dashboard.md): a long skill
// or process is not a lost reply. The server has its own run deadline below this one.
const kRunTimeoutMs = 30 * 60 * 1000;
const kLongActions = new Set(['run', 'startProcess']);
const kMaxPendingActions = 64;

export class Connection {
  constructor(url, { onMessage, onStateChange }) {
    this.url = url;
    this.onMessage = onMessage;
    this.onStateChange = onStateChange;
    this.socket = null;
    this.backoffMs = kBackoffFirstMs;
    this.nextActionId = 1;
    this.pending = new Map();  // id -> {resolve, timer, action}
    this.reconnectTimer = null;
  }

  start() { this.open(); }

  open() {
    this.reconnectTimer = null;
    this.onStateChange('connecting');
    let socket;
    try {
      socket = new WebSocket(this.url);
    } catch (error) {
      this.scheduleReconnect(String(error));
      return;
    }
    this.socket = socket;
    socket.addEventListener('open', () => {
      this.backoffMs = kBackoffFirstMs;
      this.onStateChange('open');
    });
    socket.addEventListener('message', (event) => this.receive(event.data));
    socket.addEventListener('close', (event) => {
      if (this.socket !== socket) return;
      this.socket = null;
      this.failPending('connection closed');
      this.scheduleReconnect(event.reason || `code ${event.code}`);
    });
    // 'error' is always followed by 'close'; the reconnect happens there.
  }

  scheduleReconnect(reason) {
    if (this.reconnectTimer !== null) return;
    const delay = this.backoffMs * (0.75 + Math.random() * 0.5);
    this.backoffMs = Math.min(this.backoffMs * 2, kBackoffMaxMs);
    this.onStateChange('closed', `${reason}; reconnecting in ${(delay / 1000).toFixed(1)} s`);
    this.reconnectTimer = setTimeout(() => this.open(), delay);
  }

  receive(data) {
    let message;
    try {
      message = JSON.parse(data);
    } catch {
      console.warn('dashboard: ignored a frame that is not JSON');
      return;
    }
    if (!message || typeof message !== 'object' || typeof message.type !== 'string') {
      console.warn('dashboard: ignored a message without a type');
      return;
    }
    if (message.type === 'reply') {
      const entry = this.pending.get(message.id);
      if (entry) message.label = entry.label;
      this.settle(message);
    }
    this.onMessage(message);
  }

  // Sends {id, action, ...fields}; resolves with the server's reply, or with a local failure
  // {ok:false, status:'local', message}. Never rejects.
  // label: what the page shows with the reply (e.g. "run robot/Delay").
  request(action, fields = {}, label = action) {
    return new Promise((resolve) => {
      const socket = this.socket;
      if (!socket || socket.readyState !== WebSocket.OPEN) {
        resolve({ ok: false, local: true, status: 'NotConnected', message: 'not connected to the dashboard' });
        return;
      }
      if (this.pending.size >= kMaxPendingActions) {
        resolve({ ok: false, local: true, status: 'TooManyRequests', message: 'too many actions in flight' });
        return;
      }
      const id = this.nextActionId++;
      const deadlineMs = kLongActions.has(action) ? kRunTimeoutMs : kActionTimeoutMs;
      const timer = setTimeout(() => {
        this.pending.delete(id);
        resolve({ id, ok: false, local: true, status: 'Timeout',
                  message: `no reply to ${action} within ${deadlineMs / 1000} s` });
      }, deadlineMs);
      this.pending.set(id, { resolve, timer, action, label });
      socket.send(JSON.stringify({ id, action, ...fields }));
    });
  }

  settle(reply) {
    const entry = this.pending.get(reply.id);
    if (!entry) return;
    this.pending.delete(reply.id);
    clearTimeout(entry.timer);
    entry.resolve(reply);
  }

  failPending(reason) {
    for (const [id, entry] of this.pending) {
      clearTimeout(entry.timer);
      entry.resolve({ id, ok: false, local: true, status: 'ConnectionLost', message: reason });
    }
    this.pending.clear();
  }
}
