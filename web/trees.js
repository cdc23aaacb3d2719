/**
 * @file The trees panel: the list of stored trees (name, format, analysis
 * counts and branching patterns), generating a procedural tree, and
 * uploading files by picker or drag and drop.
 *
 * The list is the API's, newest first, paged with `next_cursor` ("Load
 * more"). Creating or deleting a tree updates the list in place instead of
 * reloading it, so a tree being viewed keeps its place.
 */

/** The presets `POST /v1/trees/generate` knows (the server's error names them too). */
export const PRESETS = ['eucalyptus', 'maple', 'conifer', 'willow', 'shrub', 'dichotomous'];

/** Creates an element with attributes and children. */
export function h(tag, attrs = {}, ...children) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k === 'class') el.className = v;
    else if (k.startsWith('on')) el.addEventListener(k.slice(2), v);
    else el.setAttribute(k, v === true ? '' : String(v));
  }
  for (const c of children.flat()) if (c !== null && c !== undefined) el.append(c);
  return el;
}

/** "1,234" */
const n = (v) => Number(v ?? 0).toLocaleString('en');

export class TreesPanel {
  /**
   * @param {object} els
   * @param {HTMLUListElement} els.list
   * @param {HTMLButtonElement} els.more
   * @param {HTMLElement} els.empty
   * @param {HTMLFormElement} els.generate
   * @param {HTMLFormElement} els.upload
   * @param {import('./api.js').Api} api
   * @param {object} hooks
   * @param {(tree: object) => void} hooks.onView The user wants to see a tree.
   * @param {(trees: object[]) => void} hooks.onChange The list changed.
   * @param {(error: Error, context: string) => void} hooks.report Shows an error.
   * @param {(message: string) => void} hooks.status Announces progress.
   */
  constructor(els, api, hooks) {
    this.els = els;
    this.api = api;
    this.hooks = hooks;
    /** @type {object[]} */
    this.trees = [];
    this.cursor = null;
    this.viewedId = null;

    const preset = els.generate.elements.namedItem('preset');
    for (const p of PRESETS) preset.append(h('option', { value: p }, p));
    preset.value = 'maple';
    els.generate.addEventListener('submit', (e) => {
      e.preventDefault();
      this.generate();
    });
    els.upload.addEventListener('submit', (e) => {
      e.preventDefault();
      const input = els.upload.elements.namedItem('file');
      const name = els.upload.elements.namedItem('name').value.trim();
      if (!input.files.length) {
        hooks.report(new Error('choose a .glb, .gltf or tree .json file first'), 'uploading');
        return;
      }
      this.upload([...input.files], name).then(() => els.upload.reset());
    });
    els.more.addEventListener('click', () => this.load(this.cursor));
  }

  /** Loads the first page (or the page after `cursor`). */
  async load(cursor = null) {
    try {
      const page = await this.api.listTrees({ limit: 50, cursor: cursor || undefined });
      this.trees = cursor ? [...this.trees, ...page.items] : page.items;
      this.cursor = page.next_cursor || null;
      this.render();
    } catch (e) {
      this.hooks.report(e, 'listing trees');
    }
  }

  /** Generates a tree from the form; returns it (or null on error). */
  async generate() {
    const f = this.els.generate.elements;
    const button = this.els.generate.querySelector('button[type=submit]');
    const preset = f.namedItem('preset').value;
    const seed = Number(f.namedItem('seed').value || 0);
    const sizeText = f.namedItem('size').value.trim();
    button.disabled = true;
    this.hooks.status(`Generating ${preset} (seed ${seed})…`);
    try {
      const tree = await this.api.generateTree({ preset, seed, size: sizeText === '' ? undefined : Number(sizeText) });
      this.added(tree);
      this.hooks.status(`Generated ${tree.name}.`);
      return tree;
    } catch (e) {
      this.hooks.report(e, `generating ${preset}`);
      this.hooks.status('');
      return null;
    } finally {
      button.disabled = false;
    }
  }

  /** Uploads files one after the other; views the last one stored. */
  async upload(files, name = '') {
    for (const file of files) {
      this.hooks.status(`Uploading ${file.name}…`);
      try {
        const tree = await this.api.uploadTree(file, files.length === 1 ? name : '');
        this.added(tree);
        this.hooks.status(`Uploaded ${tree.name}.`);
      } catch (e) {
        this.hooks.report(e, `uploading ${file.name}`);
        this.hooks.status('');
      }
    }
  }

  /** Puts a new tree at the top and views it. */
  added(tree) {
    this.trees = [tree, ...this.trees.filter((t) => t.id !== tree.id)];
    this.render();
    this.hooks.onView(tree);
  }

  async remove(tree) {
    if (!confirm(`Delete the tree “${tree.name}”?`)) return;
    try {
      await this.api.deleteTree(tree.id);
      this.trees = this.trees.filter((t) => t.id !== tree.id);
      this.render();
      this.hooks.status(`Deleted ${tree.name}.`);
    } catch (e) {
      this.hooks.report(e, `deleting ${tree.name}`);
    }
  }

  /** Marks the tree on screen. */
  setViewed(id) {
    this.viewedId = id;
    for (const li of this.els.list.children) {
      const on = li.dataset.id === id;
      li.classList.toggle('viewed', on);
      li.querySelector('.tree-view').setAttribute('aria-pressed', String(on));
    }
  }

  render() {
    const { list, more, empty } = this.els;
    list.replaceChildren(...this.trees.map((t) => this.item(t)));
    more.hidden = !this.cursor;
    empty.hidden = this.trees.length > 0;
    this.setViewed(this.viewedId);
    this.hooks.onChange(this.trees);
  }

  item(tree) {
    const s = tree.stats || {};
    const p = s.patterns || {};
    return h(
      'li',
      { class: 'tree', 'data-id': tree.id },
      h(
        'div',
        { class: 'tree-head' },
        h('button', { type: 'button', class: 'tree-view', 'aria-pressed': 'false', title: 'Show this tree', onclick: () => this.hooks.onView(tree) }, tree.name),
        h('span', { class: 'badge' }, tree.format),
        h('button', { type: 'button', class: 'tree-delete icon', 'aria-label': `Delete ${tree.name}`, title: 'Delete', onclick: () => this.remove(tree) }, '×'),
      ),
      h(
        'p',
        { class: 'stats' },
        `${n(s.branches)} branches · ${n(s.chains)} chains in ${n(s.chain_groups)} groups · ${n(s.leaves)} leaves` +
          (s.height ? ` · ${Number(s.height).toFixed(1)} m` : ''),
      ),
      h('p', { class: 'patterns' }, `patterns: ${n(p.alternate)} alternate, ${n(p.opposite)} opposite, ${n(p.whorled)} whorled`),
    );
  }
}
