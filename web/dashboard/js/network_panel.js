// The network: LDS-MEs and the servers registered with them, as a tree by `parent` (the URL
// of the LDS-ME a server is registered with). Incremental: an add or remove touches only
// that server's node; children that arrive before their parent wait at the root and move
// under it when it appears.
import { el } from './dom.js';

export class NetworkPanel {
  constructor(root, emptyNote) {
    this.root = root;
    this.emptyNote = emptyNote;
    this.nodes = new Map();  // url -> {server, li, children(ul)}
  }

  reset(servers) {
    this.nodes.clear();
    this.root.replaceChildren();
    for (const server of servers || []) this.add(server);
    this.updateEmpty();
  }

  add(server) {
    if (!server || typeof server.url !== 'string') return;
    const existing = this.nodes.get(server.url);
    if (existing) {
      existing.server = server;
      this.fill(existing);
      this.place(existing);
      return;
    }
    const children = el('ul');
    const li = el('li', { class: 'server', 'data-server': server.url });
    const node = { server, li, children, label: el('div') };
    li.append(node.label, children);
    this.fill(node);
    this.nodes.set(server.url, node);
    this.place(node);
    // Servers that named this one as parent before it was known.
    for (const other of this.nodes.values()) {
      if (other !== node && other.server.parent === server.url) this.place(other);
    }
    this.updateEmpty();
  }

  remove(url) {
    const node = this.nodes.get(url);
    if (!node) return;
    this.nodes.delete(url);
    node.li.remove();
    // Its children stay visible at the root until they are removed themselves.
    for (const child of [...node.children.children]) this.root.append(child);
    this.updateEmpty();
  }

  fill(node) {
    const { server } = node;
    const caps = Array.isArray(server.capabilities) ? server.capabilities.join(', ') : '';
    const parts = [el('span', { class: 'server-name', text: server.name || server.applicationUri || server.url })];
    if (caps) parts.push(el('span', { class: 'server-caps', text: `[${caps}]` }));
    parts.push(el('div', { class: 'server-url', text: server.url }));
    if (server.error) parts.push(el('div', { class: 'server-error', text: server.error }));
    node.label.replaceChildren(...parts);
    node.li.title = server.applicationUri || '';
  }

  place(node) {
    const parent = node.server.parent ? this.nodes.get(node.server.parent) : undefined;
    // A parent loop (bad data) would make a node its own ancestor: such a node stays at the root.
    const nested = parent && parent !== node && !node.li.contains(parent.li);
    const container = nested ? parent.children : this.root;
    if (node.li.parentNode !== container) container.append(node.li);
  }

  updateEmpty() { this.emptyNote.hidden = this.nodes.size > 0; }

  count() { return this.nodes.size; }
}
