// The MES process: its run (execution, process IRI, state), its steps with the running one
// marked, and the results. A `process` message carries the whole (small) run, so the panel
// redraws it whole.
import { el } from './dom.js';

const kMaxSteps = 500;

export class ProcessPanel {
  // skillLabel(id) -> "component / skill" for the skill the process runs now (activeSkill).
  constructor(root, skillLabel) {
    this.root = root;
    this.skillLabel = skillLabel;
  }

  show(process) {
    if (!process) {
      this.root.replaceChildren(el('p', { class: 'empty', text: 'no process run yet' }));
      return;
    }
    const steps = Array.isArray(process.steps) ? process.steps.slice(0, kMaxSteps) : [];
    const running = process.running ?? null;
    const summary = el('div', { class: 'process-summary', 'data-process-state': process.state || '' },
        el('div', {}, el('b', { text: 'Process ' }), process.processIri || '?'),
        el('div', { text: `state ${process.state || '?'}` +
                          (process.execution ? ` · execution ${process.execution}` : '') +
                          (process.result ? ` · result ${process.result}` : '') }),
        process.activeSkill ? el('div', { class: 'process-active', text: `running ${this.skillLabel(process.activeSkill)}` }) : null,
        process.reason ? el('div', { class: 'result', 'data-result': 'Failed', text: process.reason }) : null);
    const rows = steps.map((step) => el('tr', { 'data-running': String(step.index === running) },
        el('td', { text: step.index }),
        el('td', { text: step.label || '' }),
        el('td', { text: step.skillType || '' }),
        el('td', { text: step.component || '' }),
        el('td', { text: step.result || (step.index === running ? 'running…' : ''), title: step.message || '' }),
        el('td', { text: Number.isFinite(step.durationS) ? `${step.durationS.toFixed(2)} s` : '' })));
    const table = el('table', { class: 'steps' },
        el('thead', {}, el('tr', {}, ...['#', 'step', 'skill type', 'component', 'result', 'time']
                                         .map((h) => el('th', { text: h })))),
        el('tbody', {}, ...rows));
    this.root.replaceChildren(summary, steps.length ? table : el('p', { class: 'empty', text: 'no steps' }));
  }
}
