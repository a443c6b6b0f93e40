// Small DOM helpers, so the pages build elements without a framework.

/**
 * Creates an element. `props`: `class`, `text`, `dataset` (an object),
 * `on` (event name -> listener), `style` ("name: value; ..." set property by
 * property through the CSSOM: the Content-Security-Policy refuses style
 * attributes) and any other attribute; a null or false attribute is left out. Children are nodes or strings (added as text,
 * never parsed as HTML: device strings cannot inject markup).
 */
export function h(tag, props = {}, ...children) {
  const el = document.createElement(tag);
  for (const [key, value] of Object.entries(props)) {
    if (value === null || value === undefined || value === false) continue;
    if (key === 'class') el.className = value;
    else if (key === 'text') el.textContent = value;
    else if (key === 'dataset') Object.assign(el.dataset, value);
    else if (key === 'on') for (const [event, fn] of Object.entries(value)) el.addEventListener(event, fn);
    else if (key === 'style') {
      for (const declaration of String(value).split(';')) {
        const at = declaration.indexOf(':');
        if (at > 0) el.style.setProperty(declaration.slice(0, at).trim(), declaration.slice(at + 1).trim());
      }
    }
    else el.setAttribute(key, value === true ? '' : value);
  }
  for (const child of children.flat()) {
    if (child === null || child === undefined || child === false) continue;
    el.append(child instanceof Node ? child : String(child));
  }
  return el;
}

export const $ = (selector, root = document) => root.querySelector(selector);

/** A local wall-clock time, HH:MM:SS. */
export function clock(ms = Date.now()) {
  return new Date(ms).toLocaleTimeString([], { hour12: false });
}

/** Shows `text` in `el` (and reveals it), or hides it when text is empty. */
export function showMessage(el, text, kind = 'error') {
  el.textContent = text || '';
  el.dataset.kind = kind;
  el.hidden = !text;
}

/** An age in words: "0.4 s ago", "12 s ago", "3 min ago". */
export function ageText(ms) {
  if (ms < 10000) return `${(Math.max(0, ms) / 1000).toFixed(1)} s ago`;
  if (ms < 120000) return `${Math.floor(ms / 1000)} s ago`;
  return `${Math.floor(ms / 60000)} min ago`;
}

/**
 * Marks `el` (a live value) with its age: `data-age-ms`, and stale (class
 * and `data-stale`) once older than `staleAfterMs`, its expected period
 * with a margin (issue 21 point 5). `ageEl` gets the age in words.
 */
export function markAge(el, ageEl, ageMs, staleAfterMs) {
  const stale = ageMs > staleAfterMs;
  el.classList.toggle('stale', stale);
  el.dataset.stale = stale ? 'yes' : 'no';
  el.dataset.ageMs = String(Math.round(ageMs));
  if (ageEl) {
    ageEl.textContent = ageText(ageMs);
    ageEl.title = stale ? `Stale: expected at least every ${(staleAfterMs / 1000).toFixed(1)} s` : '';
  }
}

// Each element `updateRows` placed, as it was built (its outerHTML then).
const builtAs = new WeakMap();
const built = (el) => {
  if (!builtAs.has(el)) builtAs.set(el, el.outerHTML);
  return builtAs.get(el);
};

/**
 * Makes `rows` (elements built afresh, each with a `data-key`) the children
 * of `parent`, keeping the elements already shown where nothing changed: a
 * row built the same is kept whole, and in a changed row each child element
 * built the same (a cell, a link, a button) is kept (a changed row with
 * text of its own, a link's, is replaced whole). A table redrawn at every
 * event or poll would otherwise replace a link or a button between touch
 * and release, and the tap would be lost. Compared as built, not as shown:
 * a button showing that it is busy is still the same button.
 */
export function updateRows(parent, rows) {
  const shown = new Map();
  for (const child of parent.children) if (child.dataset.key !== undefined) shown.set(child.dataset.key, child);
  const wanted = rows.map((row) => {
    const was = shown.get(row.dataset.key);
    const html = row.outerHTML;
    const elementsOnly = row.childNodes.length === row.children.length;
    if (!was || was.tagName !== row.tagName || was.children.length !== row.children.length
      || (!elementsOnly && built(was) !== html)) {
      builtAs.set(row, html);
      for (const child of row.children) built(child);
      return row;
    }
    if (built(was) === html) return was;
    for (const name of was.getAttributeNames()) if (!row.hasAttribute(name)) was.removeAttribute(name);
    for (const name of row.getAttributeNames()) was.setAttribute(name, row.getAttribute(name));
    [...row.children].forEach((child, i) => {
      const old = was.children[i];
      if (built(old) !== child.outerHTML) {
        builtAs.set(child, child.outerHTML);
        old.replaceWith(child);
      }
    });
    builtAs.set(was, html);
    return was;
  });
  const keep = new Set(wanted);
  for (const child of [...parent.childNodes]) if (!keep.has(child)) child.remove();
  wanted.forEach((el, i) => {
    const at = parent.children[i];
    if (at !== el) parent.insertBefore(el, at || null);
  });
}
