// Plots on plain canvases: skill durations per skill type (every run as a dot, the median as a
// bar) and the detection times (plug-in → skills detected) in order of detection. Redrawn at
// most once per animation frame, only when their data changed.

const kMaxSamplesPerSeries = 200;
const kMaxTypes = 40;

function median(values) {
  if (!values.length) return NaN;
  const sorted = [...values].sort((a, b) => a - b);
  const mid = sorted.length >> 1;
  return sorted.length % 2 ? sorted[mid] : (sorted[mid - 1] + sorted[mid]) / 2;
}

function shortType(type) {
  const text = String(type);
  const cut = Math.max(text.lastIndexOf('/'), text.lastIndexOf('#'), text.lastIndexOf('='));
  return (cut >= 0 ? text.slice(cut + 1) : text).replace(/SkillType$/, '');
}

function niceMax(value) {
  if (!(value > 0)) return 1;
  const magnitude = 10 ** Math.floor(Math.log10(value));
  for (const step of [1, 2, 2.5, 5, 10]) if (step * magnitude >= value) return step * magnitude;
  return 10 * magnitude;
}

function finiteNumbers(list) {
  return (Array.isArray(list) ? list : []).map(Number).filter(Number.isFinite);
}

export class PlotsPanel {
  constructor(durationCanvas, detectionCanvas) {
    this.durationCanvas = durationCanvas;
    this.detectionCanvas = detectionCanvas;
    this.durations = new Map();  // skill type -> [ms]
    this.detections = [];        // ms
    this.dirty = false;
  }

  reset(stats) {
    this.durations.clear();
    this.detections = [];
    this.merge(stats);
  }

  // stats: {detectionMs:[...], skillDurations:{type:[ms...]}} — replaces the series it names.
  merge(stats) {
    if (!stats || typeof stats !== 'object') return;
    if (Array.isArray(stats.detectionMs)) {
      this.detections = finiteNumbers(stats.detectionMs).slice(-kMaxSamplesPerSeries);
    }
    if (stats.skillDurations && typeof stats.skillDurations === 'object') {
      for (const [type, list] of Object.entries(stats.skillDurations)) {
        if (!this.durations.has(type) && this.durations.size >= kMaxTypes) continue;
        this.durations.set(type, finiteNumbers(list).slice(-kMaxSamplesPerSeries));
      }
    }
    this.invalidate();
  }

  addDuration(type, ms) {
    if (!Number.isFinite(ms) || ms < 0) return;
    let list = this.durations.get(type);
    if (!list) {
      if (this.durations.size >= kMaxTypes) return;
      list = [];
      this.durations.set(type, list);
    }
    list.push(ms);
    if (list.length > kMaxSamplesPerSeries) list.shift();
    this.invalidate();
  }

  addDetection(ms) {
    if (!Number.isFinite(ms) || ms < 0) return;
    this.detections.push(ms);
    if (this.detections.length > kMaxSamplesPerSeries) this.detections.shift();
    this.invalidate();
  }

  invalidate() {
    if (this.dirty) return;
    this.dirty = true;
    requestAnimationFrame(() => {
      this.dirty = false;
      this.drawDurations();
      this.drawDetections();
    });
  }

  drawDurations() {
    const canvas = this.durationCanvas;
    const g = canvas.getContext('2d');
    const types = [...this.durations.keys()].sort();
    const rowHeight = 18;
    const height = Math.max(60, 28 + types.length * rowHeight);
    if (canvas.height !== height) canvas.height = height;
    g.clearRect(0, 0, canvas.width, canvas.height);
    g.font = '11px system-ui, sans-serif';
    if (!types.length) {
      g.fillStyle = '#6b7280';
      g.fillText('no skill run yet', 8, 20);
      return;
    }
    const left = 150;
    const right = canvas.width - 12;
    const maxMs = niceMax(Math.max(...types.flatMap((t) => this.durations.get(t))));
    const x = (ms) => left + (right - left) * Math.min(ms / maxMs, 1);
    this.axis(g, left, right, canvas.height - 16, maxMs, 'ms');
    types.forEach((type, row) => {
      const y = 12 + row * rowHeight;
      const list = this.durations.get(type);
      g.fillStyle = '#1d2330';
      g.fillText(`${shortType(type)} (${list.length})`.slice(0, 24), 4, y + 4);
      g.fillStyle = 'rgba(37, 99, 235, 0.45)';
      for (const ms of list) g.fillRect(x(ms) - 1.5, y - 3, 3, 7);
      const m = median(list);
      g.fillStyle = '#b91c1c';
      g.fillRect(x(m) - 1, y - 6, 2, 13);
    });
  }

  drawDetections() {
    const canvas = this.detectionCanvas;
    const g = canvas.getContext('2d');
    g.clearRect(0, 0, canvas.width, canvas.height);
    g.font = '11px system-ui, sans-serif';
    const list = this.detections;
    if (!list.length) {
      g.fillStyle = '#6b7280';
      g.fillText('no detection measured yet', 8, 20);
      return;
    }
    const left = 40;
    const right = canvas.width - 12;
    const top = 10;
    const bottom = canvas.height - 18;
    const maxMs = niceMax(Math.max(...list));
    const y = (ms) => bottom - (bottom - top) * Math.min(ms / maxMs, 1);
    g.strokeStyle = '#dde1e7';
    g.fillStyle = '#6b7280';
    for (let i = 0; i <= 4; ++i) {
      const value = (maxMs * i) / 4;
      g.beginPath();
      g.moveTo(left, y(value));
      g.lineTo(right, y(value));
      g.stroke();
      g.fillText(`${Math.round(value)}`, 2, y(value) + 4);
    }
    g.fillText('ms, by detection', left, canvas.height - 4);
    const step = (right - left) / Math.max(list.length, 1);
    g.fillStyle = '#15803d';
    list.forEach((ms, i) => g.fillRect(left + i * step + 1, y(ms), Math.max(step - 2, 1), bottom - y(ms)));
    g.fillStyle = '#b91c1c';
    g.fillText(`median ${median(list).toFixed(0)} ms`, right - 110, top + 8);
  }

  axis(g, left, right, y, maxMs, unit) {
    g.strokeStyle = '#dde1e7';
    g.fillStyle = '#6b7280';
    for (let i = 0; i <= 4; ++i) {
      const x = left + ((right - left) * i) / 4;
      g.beginPath();
      g.moveTo(x, 4);
      g.lineTo(x, y);
      g.stroke();
      g.fillText(`${Math.round((maxMs * i) / 4)}${i === 4 ? ` ${unit}` : ''}`, Math.min(x - 8, right - 40), y + 12);
    }
  }
}
