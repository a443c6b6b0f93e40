// The PDO editor of one node (/nodes/{bus}/{node}/pdos): every RPDO and
// TPDO as a 64-bit bar of its mapped objects, an editor for the mapping
// (add from the node's mappable objects, remove, reorder by drag and drop
// or by buttons) and the transmission settings, applied with
// PUT .../pdos/{kind}/{n}. What a card shows as "on the device" is only
// ever what the gateway read back: the PUT's answer or GET .../pdos; the
// edits are a draft next to it, marked unsaved until applied or reverted.

import { api, runAction } from './api.js';
import { $, clock, h, markAge, showMessage } from './dom.js';
import { stream } from './layout.js';
import { syncControl } from './bustools.js';

const FRAME_BITS = 64;
const root = $('#pdo-page');
const bus = root.dataset.bus;
const node = root.dataset.node;
const base = `/buses/${encodeURIComponent(bus)}/nodes/${encodeURIComponent(node)}`;
const pageMessage = $('#page-message');
const lists = { tpdo: $('#tpdos'), rpdo: $('#rpdos') };

const cards = new Map(); // "tpdo/1" -> card state (see makeCard)
let mappable = { tpdo: [], rpdo: [] }; // from the node's dictionary
let liveValues = {}; // name -> newest TPDO value from the stream
let liveAges = {}; // name -> {ageMs, at}: its age as the gateway last said, at the page's time
let nmtState = null; // the node's NMT state as the gateway knows it
let syncPeriod = null; // the bus's SYNC period in ms (0: off), once read

const problems = new Map();
function problem(key, text) {
  if (text) problems.set(key, text);
  else problems.delete(key);
  showMessage(pageMessage, [...problems.values()].join(' · '));
}

// ---- what the numbers mean ---------------------------------------------

/** CiA 301 §7.2.2.2 (table 72), in words. */
export function transmissionMeaning(type, kind) {
  if (type === null || type === undefined || Number.isNaN(type)) return '';
  if (type === 0) return kind === 'tpdo' ? 'synchronous, acyclic: sent at the SYNC after an event' : 'synchronous: applied at the next SYNC';
  if (type >= 1 && type <= 240) return type === 1 ? 'synchronous: every SYNC' : `synchronous: every ${type}th SYNC`;
  if (type >= 241 && type <= 251) return 'reserved';
  if (type === 252) return 'on remote request, synchronous (RTR)';
  if (type === 253) return 'on remote request, event-driven (RTR)';
  if (type === 254) return 'event-driven, manufacturer-specific';
  if (type === 255) return 'event-driven, device profile';
  return 'not a transmission type (0–255)';
}

/** The length of a dictionary data type in bits, or null (variable size). */
export function typeBits(dataType) {
  if (dataType === 'bool') return 1;
  const m = /^[iur](\d+)$/.exec(dataType || '');
  return m ? Number(m[1]) : null;
}

const hex = (n, width = 3) => `0x${n.toString(16).toUpperCase().padStart(width, '0')}`;
const entryKey = (e) => `${e.index.toLowerCase()}:${e.sub}`;
const entryLabel = (e) => e.name || (parseInt(e.index, 16) <= 7 ? `dummy (${e.index})` : `${e.index}:${e.sub}`);
// The key the values topic uses: the EDS name, or "0x6041:0" without one.
const valueKey = (e) => e.name || `${e.index}:${e.sub}`;

/** Parses "0x181", "181h" or "385"; NaN when it is no number. */
export function parseNumber(text) {
  const t = String(text).trim();
  if (/^0x[0-9a-f]+$/i.test(t)) return parseInt(t.slice(2), 16);
  if (/^[0-9a-f]+h$/i.test(t)) return parseInt(t.slice(0, -1), 16);
  if (/^\d+$/.test(t)) return parseInt(t, 10);
  return NaN;
}

// ---- the mappable objects ------------------------------------------------

async function loadDictionary() {
  let objects;
  try {
    objects = await api(`${base}/od`);
  } catch (error) {
    problem('od', `The node's dictionary: ${error.message}`);
    return;
  }
  problem('od', null);
  const tpdo = [];
  const rpdo = [];
  for (const object of objects) {
    const hasSubs = ['array', 'record'].includes(String(object.object_type).toLowerCase());
    for (const sub of object.subs) {
      const bits = typeBits(sub.data_type);
      if (!sub.pdo_mappable || bits === null) continue;
      const entry = {
        index: object.index, sub: sub.sub, bits, data_type: sub.data_type, access: sub.access,
        name: hasSubs ? `${object.name}/${sub.name}` : object.name,
      };
      if (sub.access !== 'wo') tpdo.push(entry);
      if (!['ro', 'const'].includes(sub.access)) rpdo.push(entry);
    }
  }
  mappable = { tpdo, rpdo };
}

// ---- a card per PDO --------------------------------------------------------

const clone = (pdo) => JSON.parse(JSON.stringify(pdo));
const SETTINGS = ['cob_id', 'enabled', 'transmission_type', 'inhibit_time_100us', 'event_timer_ms', 'sync_start'];

function sameConfig(a, b) {
  for (const key of SETTINGS) if (a[key] !== b[key]) return false;
  if (a.mapping.length !== b.mapping.length) return false;
  return a.mapping.every((e, i) => entryKey(e) === entryKey(b.mapping[i]) && e.bits === b.mapping[i].bits);
}

function field(label, input, note) {
  return h('label', { class: 'field' }, h('span', { class: 'field-label' }, label), input, note || null);
}

function makeCard(kind, device) {
  const id = `${kind}-${device.number}`;
  const card = {
    kind, number: device.number, device, draft: clone(device), errors: [], badEntry: null,
    el: h('article', { class: 'pdo', id, dataset: { kind, number: device.number }, 'aria-labelledby': `${id}-title` }),
  };
  const title = h('h3', { id: `${id}-title` }, `${kind.toUpperCase()} ${device.number}`);
  card.state = h('span', { class: 'pdo-state' });
  card.dirty = h('span', { class: 'dirty', hidden: true }, 'unsaved changes');
  card.bar = h('div', { class: 'bar', role: 'img' });
  card.scale = h('div', { class: 'bar-scale', 'aria-hidden': 'true' }, h('span', {}, '0'), h('span', {}, '32'), h('span', {}, '64 bits'));
  card.entries = h('ol', { class: 'entries' });
  card.errorBox = h('div', { class: 'pdo-error', role: 'alert', hidden: true });
  card.result = h('div', { class: 'pdo-result', role: 'status', 'aria-live': 'polite' });

  // Adding an object: a search over the mappable objects of this direction.
  card.search = h('input', {
    type: 'search', class: 'search', placeholder: `Add a ${kind === 'tpdo' ? 'readable' : 'writable'} object: name or index`,
    'aria-label': `Add an object to ${kind.toUpperCase()} ${device.number}`, autocomplete: 'off',
  });
  card.matches = h('ul', { class: 'matches', role: 'listbox', hidden: true });
  card.search.addEventListener('input', () => renderMatches(card));
  card.search.addEventListener('focus', () => renderMatches(card));
  card.search.addEventListener('keydown', (event) => {
    if (event.key === 'Escape') card.matches.hidden = true;
    if (event.key === 'ArrowDown' || event.key === 'ArrowUp') {
      event.preventDefault();
      if (card.matches.hidden) renderMatches(card);
      else highlight(card, card.active + (event.key === 'ArrowDown' ? 1 : -1));
    }
    if (event.key === 'Enter') {
      event.preventDefault();
      // The highlighted entry, the one on show: never one the list hides.
      if (!card.matches.hidden) card.matches.querySelectorAll('button.match')[card.active]?.click();
    }
  });

  // Transmission settings: each input edits the draft only.
  const number = (key, min, max, extra = {}) => {
    const input = h('input', { type: 'number', inputmode: 'numeric', min, max, step: 1, name: key, ...extra });
    input.addEventListener('input', () => {
      card.draft[key] = input.value === '' ? NaN : Number(input.value);
      changed(card);
    });
    return input;
  };
  card.inputs = {
    enabled: h('input', { type: 'checkbox', name: 'enabled' }),
    cob_id: h('input', { type: 'text', name: 'cob_id', inputmode: 'text', spellcheck: 'false', autocomplete: 'off' }),
    transmission_type: number('transmission_type', 0, 255),
    inhibit_time_100us: number('inhibit_time_100us', 0, 65535),
    event_timer_ms: number('event_timer_ms', 0, 65535),
    sync_start: number('sync_start', 0, 240),
  };
  card.inputs.enabled.addEventListener('change', () => {
    card.draft.enabled = card.inputs.enabled.checked;
    changed(card);
  });
  card.inputs.cob_id.addEventListener('input', () => {
    card.draft.cob_id = parseNumber(card.inputs.cob_id.value);
    changed(card);
  });
  card.meaning = h('span', { class: 'meaning' });
  card.inhibitNote = h('span', { class: 'unit' });
  const settings = h('div', { class: 'settings' },
    h('label', { class: 'field toggle' }, card.inputs.enabled, h('span', {}, 'Enabled (valid)')),
    field('COB-ID', card.inputs.cob_id),
    field('Transmission type', card.inputs.transmission_type, card.meaning),
    field('Inhibit time (×100 µs)', card.inputs.inhibit_time_100us, card.inhibitNote),
    field('Event timer (ms)', card.inputs.event_timer_ms, h('span', { class: 'unit' }, '0 = off')),
    kind === 'tpdo' ? field('SYNC start', card.inputs.sync_start, h('span', { class: 'unit' }, '0 = any SYNC')) : null,
  );

  card.apply = h('button', { type: 'button', class: 'primary apply' }, 'Apply');
  card.revert = h('button', { type: 'button', class: 'revert' }, 'Revert');
  card.apply.addEventListener('click', () => apply(card));
  card.revert.addEventListener('click', () => {
    card.draft = clone(card.device);
    card.errors = [];
    card.badEntry = null;
    showMessage(card.errorBox, '');
    fillInputs(card);
    changed(card);
    card.result.dataset.state = '';
    card.result.textContent = 'Reverted to the configuration read from the device.';
  });

  card.el.append(
    h('header', { class: 'pdo-title' }, title, card.state, card.dirty),
    h('div', { class: 'bar-wrap' }, card.bar, card.scale),
    card.entries,
    h('div', { class: 'add' }, card.search, card.matches),
    settings,
    card.errorBox,
    h('div', { class: 'pdo-actions' }, card.apply, card.revert, card.result),
  );
  fillInputs(card);
  changed(card);
  return card;
}

/** Puts the draft into the inputs (after loading, applying, reverting). */
function fillInputs(card) {
  const { draft, inputs } = card;
  inputs.enabled.checked = draft.enabled;
  inputs.cob_id.value = Number.isNaN(draft.cob_id) ? inputs.cob_id.value : hex(draft.cob_id);
  for (const key of ['transmission_type', 'inhibit_time_100us', 'event_timer_ms', 'sync_start']) {
    const value = draft[key];
    // A parameter the node's EDS does not describe cannot be set.
    inputs[key].disabled = card.device[key] === null;
    inputs[key].placeholder = card.device[key] === null ? 'not in EDS' : '';
    inputs[key].closest('.field')?.classList.toggle('absent', card.device[key] === null);
    inputs[key].value = value === null || Number.isNaN(value) ? '' : String(value);
  }
}

/** What is wrong with the draft, found without asking the device. */
function localErrors(card) {
  const { draft } = card;
  const errors = [];
  const total = draft.mapping.reduce((sum, e) => sum + e.bits, 0);
  if (total > FRAME_BITS) errors.push(`The mapping is ${total} bits: a PDO carries at most ${FRAME_BITS}. Remove ${total - FRAME_BITS} bits.`);
  if (Number.isNaN(draft.cob_id)) errors.push('COB-ID: give a number, such as 0x181.');
  const limits = { transmission_type: [0, 255, 'Transmission type'], inhibit_time_100us: [0, 65535, 'Inhibit time'],
    event_timer_ms: [0, 65535, 'Event timer'], sync_start: [0, 240, 'SYNC start'] };
  for (const [key, [min, max, label]] of Object.entries(limits)) {
    const value = draft[key];
    if (card.device[key] === null) continue;
    if (!Number.isInteger(value) || value < min || value > max) errors.push(`${label}: a whole number from ${min} to ${max}.`);
  }
  return errors;
}

/** The draft changed: the bar, the list, the meaning and the marker. */
function changed(card) {
  const { draft, device } = card;
  card.errors = localErrors(card);
  card.meaning.textContent = transmissionMeaning(draft.transmission_type, card.kind);
  const inhibit = draft.inhibit_time_100us;
  card.inhibitNote.textContent = Number.isInteger(inhibit) ? `= ${(inhibit / 10).toLocaleString()} ms` : '';
  const dirty = !sameConfig(draft, device);
  card.dirty.hidden = !dirty;
  card.el.classList.toggle('is-dirty', dirty);
  card.revert.disabled = !dirty;
  card.state.className = `pdo-state badge ${device.enabled ? 'ok' : 'off'}`;
  card.state.textContent = `${device.enabled ? 'enabled' : 'disabled'} · COB-ID ${hex(device.cob_id)}`;
  if (card.errors.length) {
    card.errorBox.dataset.source = 'page';
    showMessage(card.errorBox, card.errors.join(' '));
  } else if (card.errorBox.dataset.source === 'page') {
    showMessage(card.errorBox, '');
  }
  renderBar(card);
  renderEntries(card);
}

function renderBar(card) {
  const { mapping } = card.draft;
  const total = mapping.reduce((sum, e) => sum + e.bits, 0);
  const over = total > FRAME_BITS;
  // Over 64 bits the bar is scaled to the whole draft, with a 64-bit mark.
  const scale = Math.max(total, FRAME_BITS);
  card.bar.classList.toggle('over', over);
  card.bar.setAttribute('aria-label', `${total} of ${FRAME_BITS} bits mapped`);
  const blocks = mapping.map((e, i) => h('div', {
    class: `block hue${i % 6}${card.badEntry === i + 1 ? ' bad' : ''}`,
    style: `flex-basis: ${(e.bits / scale) * 100}%`,
    title: `${entryLabel(e)} · ${e.index}:${e.sub} · ${e.bits} bits`,
  }, h('span', { class: 'block-name' }, entryLabel(e)), h('span', { class: 'block-bits' }, `${e.bits}`)));
  if (total < FRAME_BITS) {
    blocks.push(h('div', { class: 'block free', style: `flex-basis: ${((FRAME_BITS - total) / scale) * 100}%` },
      h('span', { class: 'block-bits' }, `${FRAME_BITS - total} free`)));
  }
  if (over) blocks.push(h('div', { class: 'limit', style: `left: ${(FRAME_BITS / scale) * 100}%` }));
  card.bar.replaceChildren(...blocks);
  // Past 64 bits the bar's middle is no longer bit 32.
  card.scale.children[1].textContent = over ? '' : '32';
  card.scale.lastChild.textContent = over ? `${total} of 64 bits` : `${total}/64 bits`;
}

function move(card, from, to) {
  const { mapping } = card.draft;
  if (to < 0 || to >= mapping.length || from === to) return;
  const [entry] = mapping.splice(from, 1);
  mapping.splice(to, 0, entry);
  changed(card);
}

let dragging = null; // {card, from}

function renderEntries(card) {
  const { mapping } = card.draft;
  const live = card.kind === 'tpdo';
  const onDevice = new Set(card.device.mapping.map(entryKey));
  if (mapping.length === 0) {
    card.entries.replaceChildren(h('li', { class: 'empty' }, 'Nothing mapped: add an object below.'));
    return;
  }
  card.entries.replaceChildren(...mapping.map((e, i) => {
    const label = entryLabel(e);
    const row = h('li', {
      class: `entry${card.badEntry === i + 1 ? ' bad' : ''}`, draggable: 'true',
      dataset: { index: e.index, sub: e.sub, position: i + 1 },
    },
    h('span', { class: 'grip', 'aria-hidden': 'true' }, '⋮⋮'),
    h('span', { class: `swatch hue${i % 6}`, 'aria-hidden': 'true' }),
    h('span', { class: 'entry-name' }, label, h('span', { class: 'sub' }, ` ${e.index}:${e.sub} · ${e.bits} bits`)),
    live && onDevice.has(entryKey(e))
      ? liveOutput(valueKey(e), card.device.transmission_type, card.device.event_timer_ms)
      : null,
    h('span', { class: 'entry-buttons' },
      h('button', { type: 'button', class: 'icon up', title: 'Move up', 'aria-label': `Move ${label} up`, disabled: i === 0,
        on: { click: () => move(card, i, i - 1) } }, '↑'),
      h('button', { type: 'button', class: 'icon down', title: 'Move down', 'aria-label': `Move ${label} down`, disabled: i === mapping.length - 1,
        on: { click: () => move(card, i, i + 1) } }, '↓'),
      h('button', { type: 'button', class: 'icon remove', title: 'Remove', 'aria-label': `Remove ${label}`,
        on: { click: () => { mapping.splice(i, 1); changed(card); } } }, '✕'),
    ));
    row.addEventListener('dragstart', (event) => {
      dragging = { card, from: i };
      event.dataTransfer.effectAllowed = 'move';
      event.dataTransfer.setData('text/plain', String(i));
      row.classList.add('dragging');
    });
    row.addEventListener('dragend', () => { dragging = null; row.classList.remove('dragging'); });
    row.addEventListener('dragover', (event) => {
      if (dragging?.card !== card) return;
      event.preventDefault();
      row.classList.add('drop-target');
    });
    row.addEventListener('dragleave', () => row.classList.remove('drop-target'));
    row.addEventListener('drop', (event) => {
      if (dragging?.card !== card) return;
      event.preventDefault();
      move(card, dragging.from, i);
      dragging = null;
    });
    return row;
  }));
}

/**
 * The mappable objects that match `query`, best first: each word of it
 * (split at spaces and underscores) in the name, or the index; an exact
 * name (without the UMC's a1_pc_ prefix) first, then the shorter name
 * ("position actual" ranks Position_actual_value above
 * Position_actual_internal_value), then the index.
 */
function rankMatches(list, query) {
  const words = query.toLowerCase().split(/[\s_]+/).filter(Boolean);
  if (words.length === 0) return list;
  const bare = words.join('_');
  const index = query.trim().toLowerCase().replace(/^0x/, '');
  const scored = [];
  for (const o of list) {
    const name = o.name.toLowerCase();
    const byName = words.every((w) => name.includes(w));
    const byIndex = `${o.index}:${o.sub}`.toLowerCase().includes(query.trim().toLowerCase())
      || o.index.toLowerCase().replace('0x', '').startsWith(index);
    if (!byName && !byIndex) continue;
    const exact = name === bare || name.endsWith(`_${bare}`) ? 0 : 1;
    scored.push({ o, key: [byIndex ? 0 : 1, exact, name.length, o.index, o.sub] });
  }
  scored.sort((x, y) => {
    for (let i = 0; i < x.key.length; i += 1) {
      if (x.key[i] < y.key[i]) return -1;
      if (x.key[i] > y.key[i]) return 1;
    }
    return 0;
  });
  return scored.map((s) => s.o);
}

/** Highlights match `n` of the card's list (wrapping round), the one Enter takes. */
function highlight(card, n) {
  const buttons = [...card.matches.querySelectorAll('button.match')];
  if (buttons.length === 0) return;
  card.active = (n + buttons.length) % buttons.length;
  buttons.forEach((button, i) => {
    const on = i === card.active;
    button.classList.toggle('active', on);
    button.parentElement.setAttribute('aria-selected', on ? 'true' : 'false');
    if (on) {
      card.search.setAttribute('aria-activedescendant', button.parentElement.id);
      button.scrollIntoView({ block: 'nearest' });
    }
  });
}

function renderMatches(card) {
  const query = card.search.value.trim();
  const used = card.draft.mapping.reduce((sum, e) => sum + e.bits, 0);
  const found = rankMatches(mappable[card.kind], query);
  if (mappable[card.kind].length === 0) {
    card.matches.replaceChildren(h('li', { class: 'none' }, 'The node\'s dictionary lists no mappable object for this direction.'));
  } else if (found.length === 0) {
    card.matches.replaceChildren(h('li', { class: 'none' }, `No mappable object matches “${card.search.value}”.`));
  } else {
    const items = found.slice(0, 12).map((o, i) => h('li', { role: 'option', id: `${card.kind}-${card.number}-match-${i}` },
      h('button', {
        type: 'button', class: `match${used + o.bits > FRAME_BITS ? ' too-big' : ''}`, tabindex: -1,
        dataset: { index: o.index, sub: o.sub },
        on: { click: () => {
          card.draft.mapping.push({ index: o.index, sub: o.sub, bits: o.bits, name: o.name });
          card.search.value = '';
          card.matches.hidden = true;
          changed(card);
        } },
      }, h('span', { class: 'match-name' }, o.name), h('span', { class: 'sub' }, ` ${o.index}:${o.sub} · ${o.data_type} · ${o.bits} bits · ${o.access}`))));
    // No "more" line for a short list (a null child would read "null").
    if (found.length > 12) items.push(h('li', { class: 'none' }, `${found.length - 12} more: type to narrow down.`));
    card.matches.replaceChildren(...items);
  }
  card.matches.hidden = false;
  highlight(card, 0);
}

document.addEventListener('click', (event) => {
  for (const card of cards.values()) {
    if (!card.search.contains(event.target) && !card.matches.contains(event.target)) card.matches.hidden = true;
  }
});

// ---- applying ---------------------------------------------------------------

/** The PUT body: the whole draft, less what the node's EDS does not have. */
function requestBody(card) {
  const body = { mapping: card.draft.mapping.map((e) => ({ index: e.index, sub: e.sub, bits: e.bits })) };
  for (const key of SETTINGS) if (card.device[key] !== null && card.device[key] !== undefined) body[key] = card.draft[key];
  return body;
}

async function apply(card) {
  changed(card);
  if (card.errors.length) {
    card.result.dataset.state = 'failed';
    card.result.textContent = 'Not sent: correct what is shown above first.';
    return;
  }
  card.badEntry = null;
  showMessage(card.errorBox, '');
  card.errorBox.dataset.source = '';
  card.result.dataset.state = 'busy';
  card.result.textContent = 'Re-mapping: invalidating the PDO, writing the mapping and the parameters, validating…';
  const path = `${base}/pdos/${card.kind}/${card.number}`;
  const result = await runAction(card.apply, 'Applying…', () => api(path, { method: 'PUT', body: requestBody(card) }));
  if (result.ok) {
    card.device = result.value;
    card.draft = clone(result.value);
    fillInputs(card);
    changed(card);
    card.result.dataset.state = 'done';
    card.result.textContent = `Applied at ${clock()}: shown as the device reports it now.`;
    return;
  }
  const { error } = result;
  const step = error.body?.error?.step;
  const entry = /mapping entry (\d+)/.exec(error.message);
  card.badEntry = entry ? Number(entry[1]) : null;
  card.errorBox.dataset.source = 'api';
  showMessage(card.errorBox, `${step ? `The device refused the step “${step}”: ` : 'Refused: '}${error.message}`);
  card.result.dataset.state = 'failed';
  card.result.textContent = `Not applied (${clock()}).`;
  changed(card);
  // A refusal half way leaves the PDO as the procedure left it: read what
  // the device has now, and keep the draft for another try.
  if (error.status === 0 || error.status >= 409) await loadPdos();
}

// ---- loading ------------------------------------------------------------------

async function loadPdos() {
  let pdos;
  try {
    pdos = await api(`${base}/pdos`);
  } catch (error) {
    problem('pdos', `Reading the PDOs: ${error.message}`);
    for (const list of Object.values(lists)) {
      if (list.querySelector('.placeholder')) list.replaceChildren(h('p', { class: 'placeholder' }, 'Could not read the PDOs.'));
    }
    return;
  }
  problem('pdos', null);
  for (const kind of ['tpdo', 'rpdo']) {
    const seen = new Set();
    for (const device of pdos[kind]) {
      const key = `${kind}/${device.number}`;
      seen.add(key);
      const card = cards.get(key);
      if (!card) {
        cards.set(key, makeCard(kind, device));
        continue;
      }
      // An edit in progress is kept; an untouched card follows the device.
      const dirty = !sameConfig(card.draft, card.device);
      card.device = device;
      if (!dirty) {
        card.draft = clone(device);
        fillInputs(card);
      }
      changed(card);
    }
    for (const key of [...cards.keys()]) if (key.startsWith(`${kind}/`) && !seen.has(key)) cards.delete(key);
    const mine = [...cards.values()].filter((c) => c.kind === kind).sort((a, b) => a.number - b.number);
    lists[kind].replaceChildren(...(mine.length ? mine.map((c) => c.el)
      : [h('p', { class: 'placeholder' }, `The node has no ${kind.toUpperCase()}.`)]));
  }
  root.dataset.loaded = 'true';
  root.dataset.loads = String(Number(root.dataset.loads || 0) + 1);
}

async function loadNode() {
  try {
    const info = await api(base);
    $('#node-name').textContent = `${info.name || 'Unnamed device'} · node ${info.id} on ${bus}`;
    nmtState = info.nmt || null;
    showValues();
    problem('node', null);
  } catch (error) {
    problem('node', `Node ${node} on ${bus}: ${error.message}`);
  }
}

// ---- live TPDO values -------------------------------------------------------

/** The newest value of a mapped object, updated in place by the stream. */
function liveOutput(key, transmissionType, eventTimer) {
  const output = h('output', { class: 'live', dataset: { key, transmission: transmissionType ?? '', eventTimer: eventTimer ?? '' } });
  const age = h('span', { class: 'age live-age', dataset: { key } });
  showValue(output);
  return h('span', { class: 'live-value' }, output, ' ', age);
}

// ---- the values' ages (issue 21 point 5) ---------------------------------
//
// The values topic publishes every value at each burst of frames, so a
// value there says nothing of its own age: GET .../values does (`age_ms`,
// no SDO), read every AGE_POLL_MS and counted on between reads; a value
// that changes on the stream is new. A value older than three of its
// periods (the SYNC period times the transmission type, or the event
// timer), or than 2 s when its period is not known, is stale, and never
// before two reads of its age.

const AGE_POLL_MS = 1000;
const DEFAULT_STALE_MS = 2000;

/** How old a value of this TPDO may be before it is stale. */
export function staleAfter(transmissionType, eventTimerMs, syncMs) {
  const type = transmissionType === '' || transmissionType === null || transmissionType === undefined ? null : Number(transmissionType);
  const timer = Number(eventTimerMs) || 0;
  let period = null;
  if (type !== null && type >= 1 && type <= 240 && syncMs > 0) period = type * syncMs;
  else if (type !== null && type >= 254 && timer > 0) period = timer;
  return period === null ? DEFAULT_STALE_MS : Math.max(3 * period, 2 * AGE_POLL_MS);
}

function renderAges() {
  const now = Date.now();
  for (const output of root.querySelectorAll('output.live')) {
    const ageEl = output.parentElement.querySelector('.live-age');
    const known = liveAges[output.dataset.key];
    if (!known || liveValues[output.dataset.key] === undefined) {
      delete output.dataset.stale;
      output.classList.remove('stale');
      if (ageEl) ageEl.textContent = '';
      continue;
    }
    markAge(output, ageEl, known.ageMs + (now - known.at),
      staleAfter(output.dataset.transmission, output.dataset.eventTimer, syncPeriod));
  }
}

async function pollAges() {
  // Only with values to age, and not while the gateway is away.
  if (!root.querySelector('output.live') || stream.state !== 'connected') return;
  try {
    const answer = await api(`${base}/values`);
    const at = Date.now();
    liveAges = {};
    for (const v of answer.values) liveAges[v.name || `${v.index}:${v.sub}`] = { ageMs: v.age_ms, at };
  } catch {
    // The next read tries again; the ages count on meanwhile.
  }
  renderAges();
}
setInterval(pollAges, AGE_POLL_MS);
setInterval(renderAges, 250);

const NMT_TEXT = { boot_up: 'booting', pre_operational: 'pre-operational', stopped: 'stopped' };

/**
 * Why a TPDO of this transmission type has not brought a value: the node
 * is not operational, or the TPDO waits for a SYNC that nobody sends, or
 * it is sent on request only; '' when nothing known stops it.
 */
export function whyNoValue(transmissionType, nmt, syncMs) {
  if (nmt && NMT_TEXT[nmt]) return `node not operational (${NMT_TEXT[nmt]}): start it with NMT`;
  const type = transmissionType === '' || transmissionType === null ? null : Number(transmissionType);
  if (type !== null && type <= 240 && syncMs === 0) return 'no SYNC running: start SYNC above';
  if (type === 252 || type === 253) return 'sent on remote request only';
  return '';
}

function showValue(output) {
  const value = liveValues[output.dataset.key];
  const why = value === undefined ? whyNoValue(output.dataset.transmission, nmtState, syncPeriod) : '';
  output.textContent = why ? `no value yet: ${why}` : formatValue(value);
  output.dataset.why = why;
  output.classList.toggle('none', value === undefined);
  output.title = value === undefined
    ? 'No TPDO with this object received since the page opened (the node sends TPDOs when operational)'
    : 'The newest value the node sent';
}

function showValues() {
  for (const output of root.querySelectorAll('output.live')) showValue(output);
}

// The bus's SYNC at hand: synchronous TPDOs are sent at its pace.
const sync = syncControl(bus, { onState: (state) => { syncPeriod = state.period_ms; showValues(); } });
$('#sync-slot').replaceWith(sync.element);

function formatValue(value) {
  if (value === undefined) return 'no value yet';
  if (value && typeof value === 'object' && 'raw' in value) return `raw ${value.raw}`;
  if (typeof value === 'number' && !Number.isInteger(value)) return value.toPrecision(6);
  return String(value);
}

const valuesTopic = `buses/${bus}/nodes/${node}/values`;
stream.subscribe([valuesTopic], (data) => {
  if (!data || typeof data !== 'object') return;
  const at = Date.now();
  for (const [key, value] of Object.entries(data)) {
    // A value that changed came in a frame just now.
    if (JSON.stringify(value) !== JSON.stringify(liveValues[key])) liveAges[key] = { ageMs: 0, at };
  }
  liveValues = { ...liveValues, ...data };
  showValues();
  renderAges();
});

// ---- start and reconnect ----------------------------------------------------

let loading = null; // the load running now, and whether another is due
let loadAgain = false;

async function loadAll() {
  if (loading) {
    loadAgain = true;
    return loading;
  }
  loading = (async () => {
    do {
      loadAgain = false;
      await Promise.all([loadDictionary(), loadNode()]);
      await loadPdos();
    } while (loadAgain);
  })();
  try {
    await loading;
  } finally {
    loading = null;
  }
}

// A gateway that just restarted finds its nodes again one by one: when
// this one is identified (or back online) its PDOs are read again.
stream.subscribe(['nodes'], (data, message) => {
  if (message.lagged) return loadAll();
  if (data.bus !== bus || String(data.node) !== node) return;
  if (data.event === 'nmt_changed' && data.nmt) {
    nmtState = data.nmt;
    showValues();
  }
  if (!['identified', 'online'].includes(data.event)) return;
  // The values topic of a node the gateway did not know yet was refused
  // (unknown_node): ask for it again now that it does.
  problem('values', null);
  stream.send({ op: 'subscribe', topics: [valuesTopic] });
  loadAll();
});

stream.onState(({ state, reconnected, error }) => {
  if (error) return problem(error.includes(valuesTopic) ? 'values' : 'stream', `Live values: ${error}`);
  if (state === 'connected') {
    problem('stream', null);
    problem('values', null);
    // The gateway may have restarted: read again what the devices have.
    if (reconnected) loadAll();
  }
});

stream.connect();
loadAll();
