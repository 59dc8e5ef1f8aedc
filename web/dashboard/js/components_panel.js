// Components and their skills. Each skill is one table row whose state / result cells are
// updated in place by `transition` messages; adds and removes touch one row or one card.
// A component is shown while the server lists it (snapshot `components`, `component`
// messages) or while it has a skill; it disappears with its last skill unless listed.
import { el, setText, shortName } from './dom.js';

const kMaxParameterText = 16384;  // the server's bound per parameter (docs/dashboard.md)

// The backend's component id (skills name it componentId); uri / name for older servers.
function componentKeyOf(component) {
  return component.id ?? component.uri ?? component.applicationUri ?? component.name;
}
function skillComponentKey(skill) { return skill.componentId ?? skill.componentUri ?? skill.component; }

function resultText(lastResult) {
  if (lastResult === undefined || lastResult === null || lastResult === '') return '';
  if (typeof lastResult !== 'object') return String(lastResult);
  const parts = [lastResult.result ?? lastResult.code ?? ''];
  if (lastResult.message) parts.push(lastResult.message);
  return parts.filter(Boolean).join(': ');
}

function resultCode(lastResult) {
  if (lastResult && typeof lastResult === 'object') return String(lastResult.result ?? '');
  return lastResult ? String(lastResult) : '';
}

// The server gives dataType as the text form `pnp skill run` parses ("Double[]"); a bare
// type name with a valueRank is shown the same way.
function parameterType(parameter) {
  const type = String(parameter.dataType ?? '?');
  if (type.endsWith(']')) return type;
  const rank = Number(parameter.valueRank);
  const array = Number.isFinite(rank) && rank >= 0 ? `[${rank > 1 ? ','.repeat(rank - 1) : ''}]` : '';
  return `${shortName(type) || '?'}${array}`;
}

function parameterText(parameter) { return `${parameter.name}: ${parameterType(parameter)}`; }

// What the text of a value looks like (docs/skill_client.md: the forms `pnp skill run` takes).
const kTextForms = { ThreeDFrame: 'x,y,z,a,b,c', ThreeDVector: 'x,y,z', Range: 'low,high' };
function parameterPlaceholder(parameter) {
  const type = parameterType(parameter);
  const base = type.replace(/\[[,]*\]$/, '');
  const form = kTextForms[base] ?? base;
  return type.endsWith(']') ? `[${form}, …]` : form;
}

export class ComponentsPanel {
  constructor(root, emptyNote, countNode, { onAction }) {
    this.root = root;
    this.emptyNote = emptyNote;
    this.countNode = countNode;
    this.onAction = onAction;
    this.components = new Map();  // key -> {name, uri, endpoint, listed, card, tbody, skillIds}
    this.skills = new Map();      // id -> {skill, row, stateNode, resultNode, formRow}
  }

  reset(components, skills) {
    this.components.clear();
    this.skills.clear();
    this.root.replaceChildren();
    // Build detached, attach once: one layout for the whole snapshot.
    const fragment = document.createDocumentFragment();
    this.attachTarget = fragment;
    for (const component of components || []) this.addComponent(component);
    for (const skill of skills || []) this.addSkill(skill);
    this.attachTarget = null;
    this.root.append(fragment);
    this.updateCounts();
  }

  ensureComponent(key, fields, listed) {
    key = String(key);
    let entry = this.components.get(key);
    if (!entry) {
      entry = { key, name: '', uri: '', appName: '', endpoint: '', listed: false, skillIds: new Set() };
      entry.nameNode = el('span', { class: 'component-name' });
      entry.endpointNode = el('span', { class: 'component-endpoint' });
      entry.tbody = el('tbody');
      entry.card = el('article', { class: 'component', 'data-component-key': key },
                      el('div', { class: 'component-head' }, entry.nameNode, entry.endpointNode),
                      el('table', { class: 'skills' }, entry.tbody));
      this.components.set(key, entry);
      (this.attachTarget || this.root).append(entry.card);
    }
    if (fields.name) entry.name = fields.name;
    if (fields.uri || fields.applicationUri) entry.uri = fields.uri || fields.applicationUri;
    if (fields.applicationName) entry.appName = fields.applicationName;
    if (fields.endpoint) entry.endpoint = fields.endpoint;
    entry.listed = entry.listed || listed;
    entry.card.dataset.componentName = entry.name || key;
    if (entry.uri) entry.card.dataset.componentUri = entry.uri;
    if (entry.appName) entry.card.dataset.componentAppName = entry.appName;
    setText(entry.nameNode, entry.name || entry.appName || key);
    setText(entry.endpointNode, entry.appName && entry.appName !== entry.name
        ? `${entry.appName} · ${entry.endpoint}` : entry.endpoint);
    entry.nameNode.title = entry.uri;
    return entry;
  }

  addComponent(component) {
    if (!component || componentKeyOf(component) === undefined) return;
    this.ensureComponent(componentKeyOf(component), component, true);
    if (!this.attachTarget) this.updateCounts();
  }

  removeComponent(keyOrName) {
    const entry = this.components.get(String(keyOrName)) ||
                  [...this.components.values()].find((c) => c.name === keyOrName);
    if (!entry) return;
    for (const id of entry.skillIds) this.skills.delete(id);
    entry.card.remove();
    this.components.delete(entry.key);
    this.updateCounts();
  }

  addSkill(skill) {
    if (!skill || skill.id === undefined || skill.id === null) return;
    const id = String(skill.id);
    const key = String(skillComponentKey(skill) ?? '(no component)');
    const known = this.skills.get(id);
    if (known && known.componentKey === key) {
      this.updateSkill(known, skill);  // a re-announced skill (e.g. its result was read)
      return;
    }
    if (known) this.removeSkill(id, { keepComponent: true });
    const component = this.ensureComponent(
        key, { name: skill.component, uri: skill.componentUri, applicationName: skill.componentName,
               endpoint: skill.endpoint }, false);

    const parameters = Array.isArray(skill.parameters) ? skill.parameters : [];
    const stateNode = el('span', { class: 'state' });
    const resultNode = el('span', { class: 'result' });
    const types = Array.isArray(skill.types) && skill.types.length ? skill.types : [skill.type];
    const entry = { skill, stateNode, resultNode, formRow: null, componentKey: key };
    const button = (label, action) =>
        el('button', { type: 'button', 'data-action': action, text: label,
                       onclick: () => this.act(id, action) });
    entry.row = el('tr', { class: 'skill', 'data-skill-id': id, 'data-skill-name': skill.name || '' },
        el('td', {}, el('div', { class: 'skill-name', text: skill.name || id }),
           el('div', { class: 'skill-type', text: shortName(skill.type), title: types.join(' → ') }),
           el('div', { class: 'skill-actions' },
              el('button', { type: 'button', 'data-action': 'run', text: 'Run',
                             onclick: () => this.toggleRunForm(id) }),
              button('Halt', 'halt'), button('Suspend', 'suspend'), button('Resume', 'resume'),
              button('Reset', 'reset'))),
        entry.paramsNode = el('td', { class: 'skill-params', text: parameters.map(parameterText).join(', ') || '—' }),
        el('td', {}, stateNode, el('div', {}, resultNode)));
    this.skills.set(id, entry);
    component.skillIds.add(id);
    component.tbody.append(entry.row);
    this.showState(entry, skill.state);
    this.showResult(entry, skill.lastResult);
    if (!this.attachTarget) this.updateCounts();
  }

  updateSkill(entry, skill) {
    entry.skill = skill;
    const parameters = Array.isArray(skill.parameters) ? skill.parameters : [];
    setText(entry.paramsNode, parameters.map(parameterText).join(', ') || '—');
    this.showState(entry, skill.state);
    this.showResult(entry, skill.lastResult);
  }

  removeSkill(id, { keepComponent = false } = {}) {
    const entry = this.skills.get(String(id));
    if (!entry) return;
    this.skills.delete(String(id));
    entry.row.remove();
    entry.formRow?.remove();
    const component = this.components.get(entry.componentKey);
    if (component) {
      component.skillIds.delete(String(id));
      if (!keepComponent && component.skillIds.size === 0 && !component.listed) {
        component.card.remove();
        this.components.delete(component.key);
      }
    }
    this.updateCounts();
  }

  // Applies a `transition`; false when the skill is unknown.
  transition(message) {
    const entry = this.skills.get(String(message.skill));
    if (!entry) return false;
    entry.skill.state = message.to;
    this.showState(entry, message.to);
    if (message.result !== undefined && message.result !== null) {
      const lastResult = message.message ? { result: message.result, message: message.message }
                                         : message.result;
      entry.skill.lastResult = lastResult;
      this.showResult(entry, lastResult);
    }
    return true;
  }

  skill(id) { return this.skills.get(String(id))?.skill; }

  showState(entry, state) {
    const text = state || '?';
    setText(entry.stateNode, text);
    entry.stateNode.dataset.state = text;
    // The server could not follow this skill (e.g. its subscription failed): say so.
    entry.stateNode.title = entry.skill.error ? String(entry.skill.error) : '';
  }

  showResult(entry, lastResult) {
    setText(entry.resultNode, resultText(lastResult));
    entry.resultNode.dataset.result = resultCode(lastResult);
  }

  act(id, action, fields = {}) {
    this.onAction(action, { skill: id, ...fields }, this.skills.get(id)?.skill);
  }

  toggleRunForm(id) {
    const entry = this.skills.get(id);
    if (!entry) return;
    if (entry.formRow) {
      entry.formRow.remove();
      entry.formRow = null;
      return;
    }
    const parameters = Array.isArray(entry.skill.parameters) ? entry.skill.parameters : [];
    const inputs = parameters.map((parameter) => el('input', {
      name: parameter.name, 'data-parameter': parameter.name, maxlength: String(kMaxParameterText),
      placeholder: parameterPlaceholder(parameter),
    }));
    const form = el('form', { class: 'run-parameters', autocomplete: 'off' },
        ...parameters.map((parameter, i) => el('label', {}, parameterText(parameter), inputs[i])),
        parameters.length ? null : el('span', { class: 'empty', text: 'no parameters' }),
        el('button', { type: 'submit', 'data-action': 'run-send', text: 'Start' }),
        el('button', { type: 'button', text: 'Cancel', onclick: () => this.toggleRunForm(id) }));
    form.addEventListener('submit', (event) => {
      event.preventDefault();
      // Only the filled fields: an empty field keeps the skill's own value.
      const values = {};
      for (const input of inputs) if (input.value !== '') values[input.name] = input.value;
      this.act(id, 'run', { parameters: values });
    });
    entry.formRow = el('tr', { class: 'run-form', 'data-run-form': id },
                       el('td', { colspan: '3' }, form));
    entry.row.after(entry.formRow);
    inputs[0]?.focus();
  }

  updateCounts() {
    this.emptyNote.hidden = this.components.size > 0;
    setText(this.countNode, `(${this.components.size} components, ${this.skills.size} skills)`);
  }
}
