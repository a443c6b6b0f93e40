// The data logger's chart: every channel against the logger's own time
// (ms from its start), each channel on a y scale of its own fitted to what
// is in view, the first four with an axis drawn in their colour. The mouse
// wheel zooms the time axis around the pointer, a drag pans it, a
// double-click (or reset()) shows everything again and follows new rows;
// the pointer's position is read out as the nearest row's values.
//
// The canvas carries data-rows (rows held), data-from and data-to (the
// time shown, ms), so that a test or a person with the inspector sees what
// the chart holds.

import { formatTick, niceStep } from './chart.js';

export const COLORS = ['#1d3557', '#e63946', '#2a9d8f', '#f4a261', '#6a4c93', '#118ab2', '#8d6e63', '#ef476f',
  '#06d6a0', '#073b4c', '#ff9f1c', '#5f0f40', '#0f4c5c', '#9a031e', '#3a86ff', '#606c38'];
const AXES = 4;
const AXIS_W = 52;
const PAD = { right: 12, top: 10, bottom: 22 };

export class LoggerChart {
  constructor(canvas, readout) {
    this.canvas = canvas;
    this.readout = readout;
    this.names = [];
    this.times = [];
    this.series = [];
    this.view = null; // null: everything, following; else {from, to}
    this.cursor = null; // pointer x in CSS pixels
    this.frame = null;
    this.drag = null;
    this.resize = new ResizeObserver(() => this.schedule());
    this.resize.observe(canvas);
    canvas.addEventListener('wheel', (event) => {
      event.preventDefault();
      this.zoom(event.deltaY < 0 ? 0.8 : 1.25, this.timeAt(event.offsetX));
    }, { passive: false });
    canvas.addEventListener('pointerdown', (event) => {
      canvas.setPointerCapture(event.pointerId);
      this.drag = { x: event.offsetX, view: this.range() };
    });
    canvas.addEventListener('pointermove', (event) => {
      this.cursor = event.offsetX;
      if (this.drag) {
        const { from, to } = this.drag.view;
        const shift = ((event.offsetX - this.drag.x) / this.plotWidth()) * (to - from);
        this.view = { from: from - shift, to: to - shift };
      }
      this.schedule();
    });
    canvas.addEventListener('pointerup', () => { this.drag = null; });
    canvas.addEventListener('pointerleave', () => { this.cursor = null; this.schedule(); });
    canvas.addEventListener('dblclick', () => this.reset());
  }

  /** Starts over with these channel names (and no rows). */
  setChannels(names) {
    this.names = names;
    this.times = [];
    this.series = names.map(() => []);
    this.view = null;
    this.schedule();
  }

  /** Adds rows `[time_ms, v1, v2, ...]` (null for a failed read). */
  addRows(rows) {
    for (const row of rows) {
      this.times.push(row[0]);
      for (let i = 0; i < this.series.length; i += 1) {
        const v = row[i + 1];
        this.series[i].push(Number.isFinite(v) ? v : null);
      }
    }
    this.canvas.dataset.rows = String(this.times.length);
    this.schedule();
  }

  axes() { return Math.min(AXES, Math.max(1, this.names.length)); }
  plotLeft() { return this.axes() * AXIS_W; }
  plotWidth() { return Math.max(1, this.canvas.clientWidth - this.plotLeft() - PAD.right); }

  /** The time range in view. */
  range() {
    if (this.view) return this.view;
    const last = this.times.length ? this.times[this.times.length - 1] : 0;
    return { from: 0, to: Math.max(last, 1) };
  }

  timeAt(px) {
    const { from, to } = this.range();
    return from + ((px - this.plotLeft()) / this.plotWidth()) * (to - from);
  }

  /** Zooms the time axis by `factor` (below 1: in) around time `at`. */
  zoom(factor, at) {
    const { from, to } = this.range();
    const center = Number.isFinite(at) ? at : (from + to) / 2;
    const span = Math.max(2, (to - from) * factor);
    const left = (center - from) / (to - from || 1);
    this.view = { from: center - span * left, to: center + span * (1 - left) };
    this.schedule();
  }

  reset() {
    this.view = null;
    this.schedule();
  }

  schedule() {
    if (this.frame === null) this.frame = requestAnimationFrame(() => {
      this.frame = null;
      this.draw();
    });
  }

  /** The index of the first row at or after `t` (binary search). */
  indexAt(t) {
    let lo = 0;
    let hi = this.times.length;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (this.times[mid] < t) lo = mid + 1;
      else hi = mid;
    }
    return lo;
  }

  draw() {
    const { canvas } = this;
    const ratio = window.devicePixelRatio || 1;
    const width = canvas.clientWidth;
    const height = canvas.clientHeight;
    if (!width || !height) return;
    if (canvas.width !== Math.round(width * ratio) || canvas.height !== Math.round(height * ratio)) {
      canvas.width = Math.round(width * ratio);
      canvas.height = Math.round(height * ratio);
    }
    const ctx = canvas.getContext('2d');
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    ctx.clearRect(0, 0, width, height);
    const { from, to } = this.range();
    canvas.dataset.from = String(Math.round(from));
    canvas.dataset.to = String(Math.round(to));
    const left = this.plotLeft();
    const plotW = this.plotWidth();
    const plotH = height - PAD.top - PAD.bottom;
    const x = (t) => left + ((t - from) / (to - from)) * plotW;
    const first = Math.max(0, this.indexAt(from) - 1);
    const last = Math.min(this.times.length, this.indexAt(to) + 1);
    ctx.font = '11px system-ui, sans-serif';

    // The time axis: ms or s, round steps.
    const step = niceStep(to - from, Math.max(2, Math.floor(plotW / 90)));
    ctx.textAlign = 'center';
    ctx.textBaseline = 'top';
    for (let t = Math.ceil(from / step) * step, i = 0; t <= to && i < 100; t += step, i += 1) {
      const px = Math.round(x(t)) + 0.5;
      ctx.strokeStyle = '#eef1f5';
      ctx.beginPath();
      ctx.moveTo(px, PAD.top);
      ctx.lineTo(px, PAD.top + plotH);
      ctx.stroke();
      ctx.fillStyle = '#5f6b7a';
      const label = step >= 1000 ? `${+(t / 1000).toFixed(step >= 1000 ? 0 : 1)} s` : `${Math.round(t)} ms`;
      ctx.fillText(label, px, PAD.top + plotH + 5);
    }

    // Each channel on its own scale.
    const scales = this.series.map((values) => {
      let lo = Infinity;
      let hi = -Infinity;
      for (let i = first; i < last; i += 1) {
        const v = values[i];
        if (v === null) continue;
        if (v < lo) lo = v;
        if (v > hi) hi = v;
      }
      if (!Number.isFinite(lo)) { lo = 0; hi = 1; }
      if (hi - lo < 1e-9) {
        const pad = Math.max(1, Math.abs(hi) * 0.05);
        lo -= pad;
        hi += pad;
      }
      const ticks = niceStep(hi - lo, Math.max(2, Math.floor(plotH / 40)));
      return { lo: Math.floor(lo / ticks) * ticks, hi: Math.ceil(hi / ticks) * ticks, ticks };
    });
    ctx.textAlign = 'right';
    ctx.textBaseline = 'middle';
    for (let a = 0; a < Math.min(AXES, scales.length); a += 1) {
      const { lo, hi, ticks } = scales[a];
      const edge = (a + 1) * AXIS_W - 4;
      ctx.strokeStyle = COLORS[a % COLORS.length];
      ctx.fillStyle = COLORS[a % COLORS.length];
      ctx.beginPath();
      ctx.moveTo(edge + 0.5, PAD.top);
      ctx.lineTo(edge + 0.5, PAD.top + plotH);
      ctx.stroke();
      for (let v = lo, i = 0; v <= hi + ticks / 2 && i < 50; v += ticks, i += 1) {
        const py = PAD.top + (1 - (v - lo) / (hi - lo)) * plotH;
        ctx.fillText(formatTick(Math.abs(v) < ticks / 2 ? 0 : v, ticks), edge - 3, py);
      }
    }

    ctx.save();
    ctx.beginPath();
    ctx.rect(left, PAD.top, plotW, plotH);
    ctx.clip();
    ctx.lineWidth = 1.5;
    ctx.lineJoin = 'round';
    this.series.forEach((values, s) => {
      const { lo, hi } = scales[s];
      const y = (v) => PAD.top + (1 - (v - lo) / (hi - lo)) * plotH;
      ctx.strokeStyle = COLORS[s % COLORS.length];
      ctx.beginPath();
      let pen = false;
      // About two rows per pixel at most: every n-th row of a long view.
      const stride = Math.max(1, Math.floor((last - first) / (plotW * 2)));
      for (let i = first; i < last; i += stride) {
        const v = values[i];
        if (v === null) { pen = false; continue; }
        const px = x(this.times[i]);
        if (pen) ctx.lineTo(px, y(v));
        else ctx.moveTo(px, y(v));
        pen = true;
      }
      ctx.stroke();
    });
    // The cursor and its read-out.
    if (this.cursor !== null && this.times.length && this.cursor >= left) {
      const t = this.timeAt(this.cursor);
      let i = Math.min(this.times.length - 1, this.indexAt(t));
      if (i > 0 && Math.abs(this.times[i - 1] - t) < Math.abs(this.times[i] - t)) i -= 1;
      const px = Math.round(x(this.times[i])) + 0.5;
      ctx.strokeStyle = '#5f6b7a';
      ctx.beginPath();
      ctx.moveTo(px, PAD.top);
      ctx.lineTo(px, PAD.top + plotH);
      ctx.stroke();
      this.showReadout(i);
    }
    ctx.restore();
  }

  /** Says the values of row `i`. */
  showReadout(i) {
    const parts = [`t = ${this.times[i]} ms`];
    this.names.forEach((name, s) => {
      const v = this.series[s][i];
      parts.push(`${name} = ${v === null ? '—' : v}`);
    });
    this.readout.textContent = parts.join('   ');
    this.readout.dataset.row = String(i);
  }

  close() {
    this.resize.disconnect();
    if (this.frame !== null) cancelAnimationFrame(this.frame);
  }
}
