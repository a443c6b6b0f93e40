// CiA 402 for the drive page (CiA 402-2 §8.1 "Power drive system"): the
// states of the state machine with their names, the transitions a master
// commands (mapped to what `POST .../axes/{axis}/state` and
// `.../fault-reset` take), the state diagram as an SVG with the current
// state lit, and the statusword's bits with their meaning in each mode.

/** The API's state names and how the page says them. */
export const STATES = {
  not_ready_to_switch_on: 'Not ready to switch on',
  switch_on_disabled: 'Switch on disabled',
  ready_to_switch_on: 'Ready to switch on',
  switched_on: 'Switched on',
  operation_enabled: 'Operation enabled',
  quick_stop_active: 'Quick stop active',
  fault_reaction_active: 'Fault reaction active',
  fault: 'Fault',
};

export const stateLabel = (state) => STATES[state] || (state ? `Unknown (${state})` : 'Not read yet');

export const isFault = (state) => state === 'fault' || state === 'fault_reaction_active';

/**
 * The transitions of the diagram (CiA 402-2 figure 7), numbered as there.
 * `target`: the state the API is asked for (`state` request), or
 * 'fault-reset' for transition 15; null for what the drive does by itself.
 * Transition 13 (any state to fault reaction active) is not drawn.
 */
export const TRANSITIONS = [
  { n: 1, from: 'not_ready_to_switch_on', to: 'switch_on_disabled', command: 'Automatic', target: null },
  { n: 2, from: 'switch_on_disabled', to: 'ready_to_switch_on', command: 'Shutdown', target: 'ready_to_switch_on' },
  { n: 3, from: 'ready_to_switch_on', to: 'switched_on', command: 'Switch on', target: 'switched_on' },
  { n: 4, from: 'switched_on', to: 'operation_enabled', command: 'Enable operation', target: 'operation_enabled' },
  { n: 5, from: 'operation_enabled', to: 'switched_on', command: 'Disable operation', target: 'switched_on' },
  { n: 6, from: 'switched_on', to: 'ready_to_switch_on', command: 'Shutdown', target: 'ready_to_switch_on' },
  { n: 7, from: 'ready_to_switch_on', to: 'switch_on_disabled', command: 'Disable voltage', target: 'switch_on_disabled' },
  { n: 8, from: 'operation_enabled', to: 'ready_to_switch_on', command: 'Shutdown', target: 'ready_to_switch_on' },
  { n: 9, from: 'operation_enabled', to: 'switch_on_disabled', command: 'Disable voltage', target: 'switch_on_disabled' },
  { n: 10, from: 'switched_on', to: 'switch_on_disabled', command: 'Disable voltage', target: 'switch_on_disabled' },
  { n: 11, from: 'operation_enabled', to: 'quick_stop_active', command: 'Quick stop', target: 'quick_stop_active' },
  { n: 12, from: 'quick_stop_active', to: 'switch_on_disabled', command: 'Disable voltage', target: 'switch_on_disabled' },
  { n: 14, from: 'fault_reaction_active', to: 'fault', command: 'Automatic', target: null },
  { n: 15, from: 'fault', to: 'switch_on_disabled', command: 'Fault reset', target: 'fault-reset' },
  { n: 16, from: 'quick_stop_active', to: 'operation_enabled', command: 'Enable operation', target: 'operation_enabled' },
];

/** The transitions a master can command from `state`, in the order shown. */
export function commandable(state) {
  return TRANSITIONS.filter((t) => t.from === state && t.target !== null);
}

// ---- the diagram -----------------------------------------------------------

const SVG_NS = 'http://www.w3.org/2000/svg';

function s(tag, attrs = {}, ...children) {
  const el = document.createElementNS(SVG_NS, tag);
  for (const [key, value] of Object.entries(attrs)) el.setAttribute(key, value);
  for (const child of children) el.append(child);
  return el;
}

const BOX_W = 172;
const BOX_H = 38;
// Where each state's box is: the power ladder on the left, the fault and
// quick stop states on the right.
const BOXES = {
  not_ready_to_switch_on: [10, 8],
  switch_on_disabled: [10, 74],
  ready_to_switch_on: [10, 140],
  switched_on: [10, 206],
  operation_enabled: [10, 272],
  fault_reaction_active: [236, 8],
  fault: [236, 74],
  quick_stop_active: [236, 272],
};

// Each drawn transition: its path and where its number goes.
const ARROWS = {
  1: { d: 'M96 46 V72', label: [104, 62] },
  2: { d: 'M70 112 V138', label: [58, 128] },
  7: { d: 'M122 140 V114', label: [130, 130] },
  3: { d: 'M70 178 V204', label: [58, 194] },
  6: { d: 'M122 206 V180', label: [130, 196] },
  4: { d: 'M70 244 V270', label: [58, 260] },
  5: { d: 'M122 272 V246', label: [130, 262] },
  11: { d: 'M182 284 H234', label: [208, 279] },
  16: { d: 'M236 300 H184', label: [208, 314] },
  12: { d: 'M300 272 L186 106', label: [266, 200] },
  14: { d: 'M322 46 V72', label: [330, 62] },
  15: { d: 'M236 88 H184', label: [210, 83] },
};

/**
 * The state diagram in `container`; returns update(state, available)
 * that lights the current state and the transitions that can be commanded.
 */
export function stateDiagram(container) {
  const svg = s('svg', {
    viewBox: '0 0 418 322', class: 'diagram', role: 'img',
    'aria-label': 'CiA 402 state diagram',
  });
  svg.append(s('defs', {}, s('marker', {
    id: 'arrowhead', viewBox: '0 0 10 10', refX: '9', refY: '5', markerWidth: '7', markerHeight: '7', orient: 'auto-start-reverse',
  }, s('path', { d: 'M0 0 L10 5 L0 10 z', fill: 'context-stroke' }))));
  const boxes = {};
  for (const [state, [x, y]] of Object.entries(BOXES)) {
    const title = s('title', {});
    title.textContent = STATES[state];
    const text = s('text', { x: x + BOX_W / 2, y: y + BOX_H / 2 + 1 });
    text.textContent = STATES[state];
    const group = s('g', { class: `state${isFault(state) ? ' fault-state' : ''}`, 'data-state': state },
      title, s('rect', { x, y, width: BOX_W, height: BOX_H, rx: 7 }), text);
    boxes[state] = group;
    svg.append(group);
  }
  const arrows = {};
  for (const [n, { d, label }] of Object.entries(ARROWS)) {
    const number = s('text', { x: label[0], y: label[1], class: 'n' });
    number.textContent = n;
    const group = s('g', { class: 'arrow', 'data-transition': n },
      s('path', { d, 'marker-end': 'url(#arrowhead)' }), number);
    arrows[n] = group;
    svg.append(group);
  }
  container.replaceChildren(svg);

  return (state, available = []) => {
    const lit = new Set(available.map((t) => String(t.n)));
    for (const [name, group] of Object.entries(boxes)) {
      group.classList.toggle('current', name === state);
    }
    for (const [n, group] of Object.entries(arrows)) group.classList.toggle('available', lit.has(n));
    svg.dataset.state = state || '';
  };
}

// ---- the statusword --------------------------------------------------------

const COMMON_BITS = [
  [0, 'Ready to switch on'],
  [1, 'Switched on'],
  [2, 'Operation enabled'],
  [3, 'Fault'],
  [4, 'Voltage enabled'],
  [5, 'Quick stop', 'Set while quick stop is NOT active (the bit is active low)'],
  [6, 'Switch on disabled'],
  [7, 'Warning'],
  [8, 'Manufacturer specific'],
  [9, 'Remote', 'The controlword is obeyed'],
  [10, 'Target reached'],
  [11, 'Internal limit active'],
];

// Bits 12 and 13 by the mode the drive displays (CiA 402-2: each mode's
// "statusword" section).
const MODE_BITS = {
  profile_position: ['Set-point acknowledge', 'Following error'],
  profile_velocity: ['Speed (zero)', 'Max slippage error'],
  homing: ['Homing attained', 'Homing error'],
  interpolated_position: ['IP mode active', 'Following error'],
  continuous_position: ['Op-mode specific', 'Following error'],
};

/** [{bit, name, on, title}] for bits 0–13 of `word`, named for `mode`. */
export function statuswordBits(word, mode) {
  const modeBits = MODE_BITS[mode] || ['Op-mode specific', 'Op-mode specific'];
  const bits = [...COMMON_BITS, [12, modeBits[0]], [13, modeBits[1]]];
  return bits.map(([bit, name, title]) => ({
    bit, name, title: title || null, on: word === null || word === undefined ? null : ((word >> bit) & 1) === 1,
  }));
}
