// The timeline of transition events, newest first, bounded: a newest-first list moves every
// row it shows at each event, so it shows only the last rows a panel can hold.
import { el, clockText } from './dom.js';

const kMaxRows = 60;

export class TimelinePanel {
  constructor(root) { this.root = root; }

  reset(transitions, skillName) {
    this.root.replaceChildren();
    const list = Array.isArray(transitions) ? transitions.slice(-kMaxRows) : [];
    const fragment = document.createDocumentFragment();
    for (let i = list.length - 1; i >= 0; --i) fragment.append(this.row(list[i], skillName));
    this.root.append(fragment);
  }

  add(transition, skillName) {
    this.root.prepend(this.row(transition, skillName));
    while (this.root.childElementCount > kMaxRows) this.root.lastElementChild.remove();
  }

  row(transition, skillName) {
    const result = transition.result ? ` (${transition.result}${transition.message ? `: ${transition.message}` : ''})` : '';
    return el('li', { 'data-skill-id': String(transition.skill) },
              el('span', { class: 'timeline-time', text: clockText(transition.time) }),
              el('span', { text: skillName(transition.skill) }),
              el('span', { text: `${transition.from ?? '?'} → ${transition.to ?? '?'}${result}` }));
  }
}
