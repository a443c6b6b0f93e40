// A small time-series chart on a canvas, for the drive page's position,
// velocity and torque: the last `windowMs` of samples, the y axis scaled to
// what is visible (with round tick values), the x axis in seconds before
// now. A null sample, or no sample for longer than `gapMs` (the stream was
// down, the gateway restarted), breaks the line instead of joining across
// the hole with a straight segment that was never measured.
//
// The canvas carries data-samples (how many samples are kept) and
// data-last (the newest value, empty when null), so that a test or a
// person with the inspector sees what the chart holds.

const DEFAULT_WINDOW_MS = 15000;
const DEFAULT_GAP_MS = 1500;
const PAD = { left: 64, right: 12, top: 10, bottom: 22 };

/** "Nice" tick step (1, 2 or 5 times a power of ten) for `span` over about `count` ticks. */
export function niceStep(span, count) {
  if (!(span > 0)) return 1;
  const raw = span / Math.max(1, count);
  const power = 10 ** Math.floor(Math.log10(raw));
  const unit = raw / power;
  const nice = unit <= 1 ? 1 : unit <= 2 ? 2 : unit <= 5 ? 5 : 10;
  return nice * power;
}

/** A value for a tick label: compact for large numbers, no float noise. */
export function formatTick(value, step) {
  const abs = Math.abs(value);
  if (abs >= 1e6) return `${+(value / 1e6).toFixed(step >= 1e6 ? 0 : 2)}M`;
  if (abs >= 1e4) return `${+(value / 1e3).toFixed(step >= 1e3 ? 0 : 1)}k`;
  const decimals = step >= 1 ? 0 : Math.min(6, Math.ceil(-Math.log10(step)));
  return value.toFixed(decimals);
}

export class TimeChart {
  /**
   * `canvas`: the element to draw on (sized by CSS; the drawing follows
   * its size and the screen's pixel ratio). `color`: the line's colour.
   */
  constructor(canvas, { color = '#1d3557', windowMs = DEFAULT_WINDOW_MS, gapMs = DEFAULT_GAP_MS } = {}) {
    this.canvas = canvas;
    this.color = color;
    this.windowMs = windowMs;
    this.gapMs = gapMs;
    this.samples = []; // {t: ms (performance.now()), v: number|null}
    this.frame = null;
    this.resize = new ResizeObserver(() => this.schedule());
    this.resize.observe(canvas);
    // The x axis moves with time even when no sample comes.
    this.ticker = setInterval(() => this.schedule(), 250);
  }

  /** Adds a sample taken now; `value` null for "not known". */
  push(value, t = performance.now()) {
    this.samples.push({ t, v: Number.isFinite(value) ? value : null });
    const oldest = t - this.windowMs - 1000;
    let drop = 0;
    while (drop < this.samples.length && this.samples[drop].t < oldest) drop += 1;
    if (drop) this.samples.splice(0, drop);
    this.canvas.dataset.samples = String(this.samples.length);
    const last = this.samples[this.samples.length - 1].v;
    this.canvas.dataset.last = last === null ? '' : String(last);
    this.schedule();
  }

  schedule() {
    if (this.frame === null) this.frame = requestAnimationFrame(() => {
      this.frame = null;
      this.draw();
    });
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

    const now = performance.now();
    const from = now - this.windowMs;
    const plotW = width - PAD.left - PAD.right;
    const plotH = height - PAD.top - PAD.bottom;
    const visible = this.samples.filter((s) => s.t >= from - this.gapMs);
    const values = visible.map((s) => s.v).filter((v) => v !== null);
    let lo = values.length ? Math.min(...values) : 0;
    let hi = values.length ? Math.max(...values) : 1;
    if (hi - lo < 1e-9) {
      // A flat line sits in the middle of a small range around it.
      const pad = Math.max(1, Math.abs(hi) * 0.05);
      lo -= pad;
      hi += pad;
    }
    const step = niceStep(hi - lo, Math.max(2, Math.floor(plotH / 28)));
    lo = Math.floor(lo / step) * step;
    hi = Math.ceil(hi / step) * step;
    const x = (t) => PAD.left + ((t - from) / this.windowMs) * plotW;
    const y = (v) => PAD.top + (1 - (v - lo) / (hi - lo)) * plotH;

    ctx.font = '11px system-ui, sans-serif';
    ctx.lineWidth = 1;
    // Horizontal grid and the y labels.
    ctx.textAlign = 'right';
    ctx.textBaseline = 'middle';
    for (let v = lo, i = 0; v <= hi + step / 2 && i < 50; v += step, i += 1) {
      const py = Math.round(y(v)) + 0.5;
      ctx.strokeStyle = Math.abs(v) < step / 2 ? '#9aa5b4' : '#e6eaf0';
      ctx.beginPath();
      ctx.moveTo(PAD.left, py);
      ctx.lineTo(PAD.left + plotW, py);
      ctx.stroke();
      ctx.fillStyle = '#5f6b7a';
      ctx.fillText(formatTick(Math.abs(v) < step / 2 ? 0 : v, step), PAD.left - 6, py);
    }
    // Vertical grid every 5 s and the x labels (seconds before now).
    ctx.textAlign = 'center';
    ctx.textBaseline = 'top';
    const seconds = Math.floor(this.windowMs / 1000);
    for (let s = 0; s <= seconds; s += 5) {
      const px = Math.round(x(now - s * 1000)) + 0.5;
      ctx.strokeStyle = '#eef1f5';
      ctx.beginPath();
      ctx.moveTo(px, PAD.top);
      ctx.lineTo(px, PAD.top + plotH);
      ctx.stroke();
      ctx.fillStyle = '#5f6b7a';
      ctx.fillText(s === 0 ? 'now' : `−${s} s`, Math.min(px, PAD.left + plotW - 12), PAD.top + plotH + 5);
    }

    // The line, clipped to the plot, broken at nulls and gaps.
    ctx.save();
    ctx.beginPath();
    ctx.rect(PAD.left, PAD.top, plotW, plotH);
    ctx.clip();
    ctx.strokeStyle = this.color;
    ctx.lineWidth = 2;
    ctx.lineJoin = 'round';
    ctx.beginPath();
    let previous = null;
    let alone = null; // a point with no neighbour is drawn as a dot
    for (const sample of visible) {
      if (sample.v === null) {
        previous = null;
        continue;
      }
      const px = x(sample.t);
      const py = y(sample.v);
      if (previous && sample.t - previous.t <= this.gapMs) {
        ctx.lineTo(px, py);
        alone = null;
      } else {
        if (alone) ctx.rect(alone[0] - 1, alone[1] - 1, 2, 2);
        ctx.moveTo(px, py);
        alone = [px, py];
      }
      previous = sample;
    }
    if (alone) ctx.rect(alone[0] - 1, alone[1] - 1, 2, 2);
    ctx.stroke();
    ctx.restore();
  }

  /** Stops redrawing (the chart is no longer shown). */
  close() {
    clearInterval(this.ticker);
    this.resize.disconnect();
    if (this.frame !== null) cancelAnimationFrame(this.frame);
  }
}
