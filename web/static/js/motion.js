// The drive page's motion forms: one per mode `POST .../axes/{axis}/move`
// accepts (docs/rest-api.md, "Routes"), each turning its inputs into the
// request body, or into a FormError that says in words which input is
// wrong before anything is sent. Values are device units; what a unit is
// depends on the product (a JMC's velocity is in 0.1 rps), said under the
// inputs.

import { h } from './dom.js';

export const MODE_LABELS = {
  profile_position: 'Profile position',
  velocity: 'Velocity',
  torque: 'Torque',
  duty_cycle: 'Duty cycle',
  continuous_position: 'Continuous position',
  interpolated_position: 'Interpolated position',
  homing: 'Homing',
};

export class FormError extends Error {}

const I32 = [-2147483648, 2147483647];
const I16 = [-32768, 32767];
const U32 = [0, 4294967295];
const MAX_IP_POINTS = 100000;

let uid = 0;

/** A labelled input; `hint` under it. */
function field(label, input, hint) {
  uid += 1;
  input.id = `motion-${uid}`;
  return h('div', { class: 'field' },
    h('label', { for: input.id }, label),
    input,
    hint ? h('div', { class: 'hint' }, hint) : null);
}

const number = (name, props = {}) => h('input', {
  type: 'number', name, inputmode: 'numeric', step: 1, autocomplete: 'off', ...props,
});

const checkbox = (name, label, checked) => h('label', { class: 'check' },
  h('input', { type: 'checkbox', name, checked: checked ? true : null }), label);

/** The whole number in `form[name]`, within [min, max]; undefined when
 * empty and optional. */
function readInt(form, name, label, [min, max], optional = false) {
  const text = form.elements[name].value.trim();
  if (text === '') {
    if (optional) return undefined;
    throw new FormError(`${label}: enter a value.`);
  }
  if (!/^[-+]?\d+$/.test(text)) throw new FormError(`${label}: “${text}” is not a whole number.`);
  const value = Number(text);
  if (value < min || value > max) throw new FormError(`${label}: ${text} is out of range (${min} to ${max}).`);
  return value;
}

const withOptional = (body, optional) => {
  for (const [key, value] of Object.entries(optional)) if (value !== undefined) body[key] = value;
  return body;
};

/** A slider and a number input that follow each other. */
function sliderPair(name, [min, max], step, initial) {
  const input = number(name, { value: initial, min, max });
  const slider = h('input', { type: 'range', min, max, step, value: initial, 'aria-label': `${name} slider`, class: 'slider' });
  slider.addEventListener('input', () => { input.value = slider.value; });
  input.addEventListener('input', () => { if (input.value !== '') slider.value = input.value; });
  return { input, slider };
}

// ---- each mode -------------------------------------------------------------

function profilePosition(units) {
  const inputs = [
    field('Target', number('target', { value: 0, required: true }), `Position (0x607A), ${units.position}`
      + `${units.softwareLimits ? `; software limits ${fmt(units.softwareLimits[0])} to ${fmt(units.softwareLimits[1])} (0x607D)` : ''}.`),
    h('div', { class: 'checks' }, checkbox('relative', 'Relative to the current target', false),
      checkbox('immediate', 'Immediately (change set at once)', true)),
    h('div', { class: 'row3' },
      field('Velocity', number('velocity', { min: 0, placeholder: 'as set' }), `Profile velocity (0x6081), ${units.velocityUnit}, optional`
        + `${units.profileCap ? `; at most ${fmt(units.profileCap[1])} (${units.profileCap[0]})` : ''}.`),
      field('Acceleration', number('acceleration', { min: 0, placeholder: 'as set' }), `0x6083, ${units.accelerationUnit}, optional.`),
      field('Deceleration', number('deceleration', { min: 0, placeholder: 'as set' }), `0x6084, ${units.accelerationUnit}, optional.`)),
  ];
  const body = (form) => withOptional({
    mode: 'profile_position',
    target: readInt(form, 'target', 'Target', I32),
    relative: form.elements.relative.checked,
    immediate: form.elements.immediate.checked,
  }, {
    velocity: readInt(form, 'velocity', 'Velocity', U32, true),
    acceleration: readInt(form, 'acceleration', 'Acceleration', U32, true),
    deceleration: readInt(form, 'deceleration', 'Deceleration', U32, true),
  });
  return { inputs, body, start: 'Move' };
}

function velocity(units) {
  const { input, slider } = sliderPair('velocity', units.velocityRange, 1, 0);
  const inputs = [
    field('Velocity', input, units.velocity),
    slider,
    h('div', { class: 'row2' },
      field('Acceleration', number('acceleration', { min: 0, placeholder: 'as set' }), units.jmc ? `0x6083, ${units.accelerationUnit}, optional.` : 'Optional.'),
      field('Deceleration', number('deceleration', { min: 0, placeholder: 'as set' }), units.jmc ? `0x6084, ${units.accelerationUnit}, optional.` : 'Optional.')),
  ];
  const body = (form) => withOptional({
    mode: 'velocity', velocity: readInt(form, 'velocity', 'Velocity', I32),
  }, {
    acceleration: readInt(form, 'acceleration', 'Acceleration', U32, true),
    deceleration: readInt(form, 'deceleration', 'Deceleration', U32, true),
  });
  // Stop: the same mode at velocity 0 (with the ramps given, if any).
  const stop = (form) => {
    input.value = 0;
    slider.value = 0;
    return withOptional({ mode: 'velocity', velocity: 0 }, {
      deceleration: readInt(form, 'deceleration', 'Deceleration', U32, true),
    });
  };
  return { inputs, body, start: 'Run', stop };
}

function torque() {
  const { input, slider } = sliderPair('torque', [-1000, 1000], 10, 0);
  const inputs = [
    field('Torque', input, 'Target torque (0x6071), per mille of the rated torque.'),
    slider,
    field('Slope', number('slope', { min: 0, placeholder: 'as set' }), 'Torque slope (0x6087), optional.'),
  ];
  const body = (form) => withOptional({ mode: 'torque', torque: readInt(form, 'torque', 'Torque', I16) },
    { slope: readInt(form, 'slope', 'Slope', U32, true) });
  const stop = (form) => {
    input.value = 0;
    slider.value = 0;
    return withOptional({ mode: 'torque', torque: 0 }, { slope: readInt(form, 'slope', 'Slope', U32, true) });
  };
  return { inputs, body, start: 'Apply', stop };
}

function dutyCycle() {
  const { input, slider } = sliderPair('duty', [-32767, 32767], 328, 0);
  const percent = h('output', { class: 'percent' }, '0.0 %');
  const show = () => {
    const value = Number(input.value);
    percent.textContent = Number.isFinite(value) ? `${((value / 32767) * 100).toFixed(1)} %` : '—';
  };
  input.addEventListener('input', show);
  slider.addEventListener('input', show);
  const inputs = [
    field('Duty', input, '0x41FA: ±32767 is ±100 % of the supply voltage.'),
    h('div', { class: 'slider-row' }, slider, percent),
    field('Slope', number('slope', { min: 0, max: 65535, placeholder: 'none' }), 'Ramp (0x41FD), optional.'),
  ];
  const body = (form) => withOptional({ mode: 'duty_cycle', duty: readInt(form, 'duty', 'Duty', I16) },
    { slope: readInt(form, 'slope', 'Slope', [0, 65535], true) });
  const stop = (form) => {
    input.value = 0;
    slider.value = 0;
    show();
    return withOptional({ mode: 'duty_cycle', duty: 0 }, { slope: readInt(form, 'slope', 'Slope', [0, 65535], true) });
  };
  return { inputs, body, start: 'Apply', stop };
}

function continuousPosition(units) {
  const inputs = [
    field('Target', number('target', { value: 0 }), `0x41F0, processed at once; ${units.position}.`),
    h('div', { class: 'checks' }, checkbox('relative', 'Relative', false)),
  ];
  const body = (form) => ({
    mode: 'continuous_position',
    target: readInt(form, 'target', 'Target', I32),
    relative: form.elements.relative.checked,
  });
  return { inputs, body, start: 'Move' };
}

/** Whole numbers separated by commas, spaces or lines. */
export function parsePoints(text) {
  const parts = text.split(/[\s,;]+/).filter(Boolean);
  if (parts.length === 0) throw new FormError('Points: enter at least one position.');
  if (parts.length > MAX_IP_POINTS) throw new FormError(`Points: at most ${MAX_IP_POINTS} (${parts.length} given).`);
  return parts.map((part, i) => {
    if (!/^[-+]?\d+$/.test(part)) throw new FormError(`Points: “${part}” (point ${i + 1}) is not a whole number.`);
    const value = Number(part);
    if (value < I32[0] || value > I32[1]) throw new FormError(`Points: ${part} (point ${i + 1}) is out of range.`);
    return value;
  });
}

function interpolatedPosition(units) {
  const points = h('textarea', { name: 'points', rows: 4, spellcheck: 'false' }, '0, 2000, 4000, 6000, 8000, 10000');
  const inputs = [
    field('Period', number('period_ms', { value: 10, min: 1, max: 255 }), 'ms between points (0x60C2), 1 to 255.'),
    field('Points', points, `Positions, ${units.position}, separated by commas or lines; fed into the drive's buffer as it drains.`),
  ];
  const body = (form) => ({
    mode: 'interpolated_position',
    period_ms: readInt(form, 'period_ms', 'Period', [1, 255]),
    points: parsePoints(form.elements.points.value),
  });
  return { inputs, body, start: 'Run points' };
}

// The JMC's methods (its manual, "Homing mode"); other drives take any
// CiA 402 method number.
const JMC_METHODS = [
  'no movement: here is home', 'left to the CW limit', 'right to the CCW limit',
  'left, origin switch', 'right, origin switch', 'left fast, CW limit, back slow',
  'right fast, CCW limit, back slow', 'left fast, origin switch, back slow',
  'right fast, origin switch, back slow', 'as 5, with offset', 'as 6, with offset',
  'as 7, with offset', 'as 8, with offset',
];

function homing(units) {
  const method = units.jmc
    ? h('select', { name: 'method' }, JMC_METHODS.map((text, n) => h('option', { value: n }, `${n}: ${text}`)))
    : number('method', { value: 0, min: -128, max: 127 });
  const inputs = [
    field('Method', method, units.jmc ? 'Homing method (0x6098).' : 'Homing method (0x6098), as the drive defines it.'),
    h('div', { class: 'row2' },
      field('Fast speed', number('fast', { min: 0, placeholder: 'as set' }), `Search for the switch (0x6099.1), ${units.velocityUnit}.`),
      field('Slow speed', number('slow', { min: 0, placeholder: 'as set' }), `Search for zero (0x6099.2), ${units.velocityUnit}.`)),
    h('div', { class: 'row2' },
      field('Acceleration', number('acceleration', { min: 0, placeholder: 'as set' }), `0x609A, ${units.accelerationUnit}, optional.`),
      field('Offset', number('offset', { placeholder: 'as set' }), `Home offset (0x607C), ${units.position}.`)),
  ];
  const body = (form) => {
    const fast = readInt(form, 'fast', 'Fast speed', U32, true);
    const slow = readInt(form, 'slow', 'Slow speed', U32, true);
    if ((fast === undefined) !== (slow === undefined)) throw new FormError('Speeds: give both or neither.');
    return withOptional({ mode: 'homing', method: readInt(form, 'method', 'Method', [-128, 127]) }, {
      speeds: fast === undefined ? undefined : [fast, slow],
      acceleration: readInt(form, 'acceleration', 'Acceleration', U32, true),
      offset: readInt(form, 'offset', 'Offset', I32, true),
    });
  };
  return { inputs, body, start: 'Start homing' };
}

const BUILDERS = {
  profile_position: profilePosition,
  velocity,
  torque,
  duty_cycle: dutyCycle,
  continuous_position: continuousPosition,
  interpolated_position: interpolatedPosition,
  homing,
};

const fmt = (value) => Number(value).toLocaleString('en-US');

/**
 * The units of an axis (`axis`: the GET axis answer, its `units` and
 * `limits` as the gateway read them; `profile`: the node's profile), said
 * in words for the forms, with the limits the drive clips requests to.
 */
export function unitsOf(profile, axis = {}) {
  const u = axis.units || {};
  const limits = axis.limits || {};
  const jmc = profile === 'jmc_stepper';
  const velocityUnit = u.velocity || (jmc ? '0.1 rps' : 'velocity units');
  // The UMC's velocity move is VL (0x6042) in vl units; the JMC's is 0x6081.
  const vl = Boolean(u.vl_velocity) && !jmc;
  const moveVelocityUnit = vl ? u.vl_velocity : velocityUnit;
  const vlMax = vl && limits.vl_max ? limits.vl_max : null;
  const profileCap = [['0x607F', limits.max_profile_velocity], ['0x6080', limits.max_motor_speed]]
    .filter(([, v]) => v !== null && v !== undefined)
    .sort((a, b) => a[1] - b[1])[0] || null;
  return {
    jmc,
    position: u.position || 'position units',
    velocityUnit,
    accelerationUnit: u.acceleration || 'acceleration units',
    moveVelocityUnit,
    velocity: vl
      ? `Target velocity (0x6042, VL), ${moveVelocityUnit}${vlMax ? `; the drive clips it to ±${fmt(vlMax)} (0x6046.2)` : ''}.`
      : `Profile velocity (0x6081) in ${velocityUnit}${u.rps_per_velocity_unit ? `: ${fmt(Math.round(1 / u.rps_per_velocity_unit * 3))} is 3 rps` : ''}.`,
    velocityRange: vlMax ? [-vlMax, vlMax] : jmc ? [-300, 300] : [-3000, 3000],
    profileCap, // [object, value]: what 0x6081 is capped to
    vlMax,
    vlMin: vl && limits.vl_min ? limits.vl_min : null,
    softwareLimits: limits.software_position_limit || null,
    acceleration: limits.profile_acceleration ?? null,
  };
}

/**
 * What the drive will clip in `body` (a move request), by `units`' limits:
 * [{what, from, to, by, unit}], `by` naming the object.
 */
export function clipsOf(body, units) {
  const clips = [];
  if (!body || !units) return clips;
  if (body.mode === 'profile_position') {
    if (body.velocity !== undefined && units.profileCap && body.velocity > units.profileCap[1]) {
      clips.push({ what: 'Profile velocity', from: body.velocity, to: units.profileCap[1], by: units.profileCap[0], unit: units.velocityUnit });
    }
    const soft = units.softwareLimits;
    if (soft && !body.relative && (body.target < soft[0] || body.target > soft[1])) {
      clips.push({ what: 'Target', from: body.target, to: Math.min(Math.max(body.target, soft[0]), soft[1]), by: '0x607D', unit: units.position });
    }
  } else if (body.mode === 'velocity' && units.vlMax !== null && Math.abs(body.velocity) > units.vlMax) {
    clips.push({ what: 'Velocity', from: body.velocity, to: Math.sign(body.velocity) * units.vlMax, by: '0x6046.2', unit: units.moveVelocityUnit });
  } else if (body.mode === 'velocity' && units.vlMin && body.velocity !== 0 && Math.abs(body.velocity) < units.vlMin) {
    clips.push({ what: 'Velocity', from: body.velocity, to: Math.sign(body.velocity) * units.vlMin, by: '0x6046.1', unit: units.moveVelocityUnit });
  }
  return clips;
}

/** A profile position move too short to reach its velocity: the peak of
 * its triangle, √(acceleration · distance), or null. */
export function peakOf(body, units, position) {
  if (!body || body.mode !== 'profile_position' || units.jmc) return null;
  const acceleration = body.acceleration ?? units.acceleration;
  if (!acceleration || position === null || position === undefined) return null;
  const distance = Math.abs(body.relative ? body.target : body.target - position);
  const clipped = clipsOf(body, units).find((c) => c.what === 'Profile velocity');
  const cruise = clipped ? clipped.to : body.velocity;
  const peak = Math.sqrt(acceleration * distance);
  return cruise !== undefined && peak < cruise ? { peak: Math.round(peak), acceleration, distance, cruise } : null;
}

/** A clip said in words. */
export function clipText({ what, from, to, by, unit }, after = false) {
  return after
    ? `${what} ${fmt(from)} clipped to ${fmt(to)} ${unit} by ${by}.`
    : `The drive will clip ${what.toLowerCase()} ${fmt(from)} to ${fmt(to)} ${unit} (${by}).`;
}

/**
 * The form of `mode`: {form, body(form), stop?(form)}: `body` and `stop`
 * give the request body or throw FormError. `onSubmit(body, button)` and
 * `onStop(body, button)` are called with a body that passed the checks.
 */
export function motionForm(mode, units, { onSubmit, onStop, onInvalid, position = () => null }) {
  const spec = BUILDERS[mode](units);
  const start = h('button', { type: 'submit', class: 'primary start', dataset: { mode } }, spec.start);
  const stop = spec.stop ? h('button', { type: 'button', class: 'stop', dataset: { mode } }, 'Stop (0)') : null;
  // Before anything is sent: what the drive will clip, and a move too
  // short to reach its velocity.
  const note = h('p', { class: 'clip-note', role: 'status', 'aria-live': 'polite', hidden: true });
  const form = h('form', { class: 'motion-form', dataset: { mode }, novalidate: true },
    ...spec.inputs, note, h('div', { class: 'actions' }, start, stop));
  const review = () => {
    let body = null;
    try {
      body = spec.body(form);
    } catch (error) {
      if (!(error instanceof FormError)) throw error;
    }
    const clips = clipsOf(body, units);
    const peak = peakOf(body, units, position());
    const lines = clips.map((clip) => clipText(clip));
    if (peak) {
      lines.push(`At ${fmt(peak.acceleration)} ${units.accelerationUnit} (0x6083) this ${fmt(peak.distance)}-${units.position} move peaks near `
        + `${fmt(peak.peak)} ${units.velocityUnit} (√(acceleration × distance)), below the profile velocity ${fmt(peak.cruise)}.`);
    }
    note.hidden = lines.length === 0;
    note.dataset.clip = clips.length ? 'yes' : 'no';
    note.textContent = lines.join(' ');
  };
  form.addEventListener('input', review);
  form.addEventListener('change', review);
  review();
  form.addEventListener('submit', (event) => {
    event.preventDefault();
    let body;
    try {
      body = spec.body(form);
    } catch (error) {
      if (error instanceof FormError) return onInvalid(error.message);
      throw error;
    }
    onSubmit(body, start, clipsOf(body, units));
  });
  if (stop) {
    stop.addEventListener('click', () => {
      let body;
      try {
        body = spec.stop(form);
      } catch (error) {
        if (error instanceof FormError) return onInvalid(error.message);
        throw error;
      }
      onStop(body, stop);
    });
  }
  return { form, buttons: [start, stop].filter(Boolean) };
}
