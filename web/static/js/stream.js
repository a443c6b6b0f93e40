// The WebSocket stream /api/v1/stream (docs/websocket.md): topics
// subscribed by handlers, and a connection that comes back by itself. After
// the socket closes (the gateway restarted, the network dropped) it is
// reopened with a growing delay, and every topic in use is subscribed again.
// It connects once the page is signed in (auth.js), with the token as a
// subprotocol.

import { protocols, whenSignedIn } from './auth.js';

const FIRST_DELAY_MS = 500;
const MAX_DELAY_MS = 8000;

export class Stream {
  /** `url`: the ws:// URL; nothing connects before connect(). */
  constructor(url) {
    this.url = url;
    this.handlers = new Map(); // topic -> Set of fn(data, message)
    this.listeners = new Set(); // fn({state, retryInMs, reconnected, error})
    this.leaseListeners = new Set(); // fn(message): renewed leases, lease errors
    this.state = 'connecting';
    this.failures = 0;
    this.everConnected = false;
    this.socket = null;
    this.timer = null;
  }

  connect() {
    clearTimeout(this.timer);
    this.setState({ state: 'connecting' });
    whenSignedIn().then(() => this.open());
  }

  open() {
    const socket = new WebSocket(this.url, protocols());
    this.socket = socket;
    socket.onopen = () => {
      if (socket !== this.socket) return;
      this.failures = 0;
      const reconnected = this.everConnected;
      this.everConnected = true;
      const topics = [...this.handlers.keys()];
      if (topics.length) this.send({ op: 'subscribe', topics });
      this.setState({ state: 'connected', reconnected });
    };
    socket.onmessage = (event) => this.receive(event.data);
    socket.onclose = () => {
      if (socket !== this.socket) return;
      this.socket = null;
      const delay = Math.min(MAX_DELAY_MS, FIRST_DELAY_MS * 2 ** this.failures);
      this.failures += 1;
      // A little jitter, so that many dashboards do not all knock at once
      // on a gateway that just came back.
      const retryInMs = Math.round(delay * (0.8 + Math.random() * 0.4));
      this.setState({ state: 'disconnected', retryInMs });
      this.timer = setTimeout(() => this.connect(), retryInMs);
    };
  }

  /** Calls `handler(data, message)` for each update of each topic; returns
   * a function that stops it (unsubscribing topics nobody listens to). */
  subscribe(topics, handler) {
    const fresh = [];
    for (const topic of topics) {
      if (!this.handlers.has(topic)) {
        this.handlers.set(topic, new Set());
        fresh.push(topic);
      }
      this.handlers.get(topic).add(handler);
    }
    if (fresh.length && this.state === 'connected') this.send({ op: 'subscribe', topics: fresh });
    return () => {
      const gone = [];
      for (const topic of topics) {
        const set = this.handlers.get(topic);
        if (!set) continue;
        set.delete(handler);
        if (set.size === 0) {
          this.handlers.delete(topic);
          gone.push(topic);
        }
      }
      if (gone.length && this.state === 'connected') this.send({ op: 'unsubscribe', topics: gone });
    };
  }

  /** Calls `fn` with the answers to lease renewals (docs/rest-api.md, "Motion
   * leases"): `{op: 'renewed', leases}` and `{op: 'error', lease, error}`. */
  onLease(fn) {
    this.leaseListeners.add(fn);
    return () => this.leaseListeners.delete(fn);
  }

  /** Calls `fn` with each change of the connection (and once now). */
  onState(fn) {
    this.listeners.add(fn);
    fn({ state: this.state });
    return () => this.listeners.delete(fn);
  }

  send(message) {
    if (this.socket && this.socket.readyState === WebSocket.OPEN) this.socket.send(JSON.stringify(message));
  }

  setState(change) {
    this.state = change.state;
    for (const fn of this.listeners) fn(change);
  }

  receive(text) {
    let message;
    try {
      message = JSON.parse(text);
    } catch {
      this.notify({ state: this.state, error: 'the gateway sent a stream message that is not JSON' });
      return;
    }
    if (message.op === 'renewed' || (message.op === 'error' && message.lease)) {
      for (const fn of this.leaseListeners) fn(message);
      return;
    }
    if (message.op === 'error') {
      const where = message.topic ? ` (topic ${message.topic})` : '';
      this.notify({ state: this.state, error: `${message.error?.message || 'stream error'}${where}` });
      return;
    }
    if (message.op) return; // subscribed / unsubscribed acknowledgements
    const handlers = this.handlers.get(message.topic);
    if (!handlers) return;
    for (const handler of handlers) handler(message.data, message);
  }

  notify(change) {
    for (const fn of this.listeners) fn(change);
  }
}

/** The stream of the gateway that served this page. */
export function streamUrl(location = window.location) {
  const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
  return `${scheme}//${location.host}/api/v1/stream`;
}
