// CANopen frames decoded for people (CiA 301 chapter 7: the predefined
// connection set of 7.3.3 gives the COB-ID of each service; SDO 7.2.4,
// NMT 7.2.8.3.1, heartbeat and node guarding 7.2.8.3.2, EMCY 7.2.7, SYNC
// 7.2.5, TIME 7.2.6; LSS is CiA 305). No DOM and no I/O: a frame in, a
// description out, so that the trace page and the tests use the same code.
//
// A frame is what the REST API and the stream give:
// {id: "0x181", extended, rtr, dlc, data: "0102AB"}. decodeFrame returns
// {service, label, node, detail, malformed}: `service` is the filter group
// (one of SERVICES), `label` the column text (TPDO1, SDO request, ...),
// `node` the node id or null, `detail` a short reading of the data, and
// `malformed` true when the data cannot be what the service sends (a
// wrong length); the detail then says what was wrong.

/** The filter groups, in the order the page lists them. */
export const SERVICES = ['nmt', 'sync', 'emcy', 'time', 'pdo', 'sdo', 'heartbeat', 'lss', 'other'];

export const SERVICE_NAMES = {
  nmt: 'NMT', sync: 'SYNC', emcy: 'EMCY', time: 'TIME', pdo: 'PDO', sdo: 'SDO',
  heartbeat: 'Heartbeat', lss: 'LSS', other: 'Other',
};

/** NMT commands (CiA 301 7.2.8.3.1), by command specifier. */
export const NMT_COMMANDS = {
  0x01: 'start', 0x02: 'stop', 0x80: 'pre-operational', 0x81: 'reset node', 0x82: 'reset communication',
};

/** NMT states of a heartbeat or guarding answer (CiA 301 7.2.8.3.2). */
export const NMT_STATES = { 0x00: 'boot-up', 0x04: 'stopped', 0x05: 'operational', 0x7f: 'pre-operational' };

/** The SDO abort codes of CiA 301 table 22, shortened. */
export const SDO_ABORTS = {
  0x05030000: 'toggle bit not alternated',
  0x05040000: 'SDO protocol timed out',
  0x05040001: 'command specifier not valid or unknown',
  0x05040002: 'invalid block size',
  0x05040003: 'invalid sequence number',
  0x05040004: 'CRC error',
  0x05040005: 'out of memory',
  0x06010000: 'unsupported access to an object',
  0x06010001: 'attempt to read a write only object',
  0x06010002: 'attempt to write a read only object',
  0x06020000: 'object does not exist',
  0x06040041: 'object cannot be mapped to the PDO',
  0x06040042: 'PDO length exceeded',
  0x06040043: 'general parameter incompatibility',
  0x06040047: 'general internal incompatibility',
  0x06060000: 'access failed due to a hardware error',
  0x06070010: 'data type does not match (length)',
  0x06070012: 'data type does not match (too long)',
  0x06070013: 'data type does not match (too short)',
  0x06090011: 'sub-index does not exist',
  0x06090030: 'invalid value',
  0x06090031: 'value too high',
  0x06090032: 'value too low',
  0x06090036: 'maximum less than minimum',
  0x060a0023: 'resource not available',
  0x08000000: 'general error',
  0x08000020: 'data cannot be transferred or stored',
  0x08000021: 'cannot transfer: local control',
  0x08000022: 'cannot transfer: device state',
  0x08000023: 'no object dictionary',
  0x08000024: 'no data available',
};

/** LSS command specifiers (CiA 305), the ones a trace shows most. */
const LSS_COMMANDS = {
  0x04: 'switch state global', 0x11: 'configure node-ID', 0x13: 'configure bit timing',
  0x15: 'activate bit timing', 0x17: 'store configuration',
  0x40: 'switch selective vendor-ID', 0x41: 'switch selective product code',
  0x42: 'switch selective revision', 0x43: 'switch selective serial', 0x44: 'switch selective done',
  0x46: 'identify vendor-ID', 0x47: 'identify product code', 0x48: 'identify revision low',
  0x49: 'identify revision high', 0x4a: 'identify serial low', 0x4b: 'identify serial high',
  0x4c: 'identify non-configured', 0x4f: 'identify slave', 0x50: 'non-configured slave',
  0x51: 'fastscan', 0x5a: 'inquire vendor-ID', 0x5b: 'inquire product code',
  0x5c: 'inquire revision', 0x5d: 'inquire serial', 0x5e: 'inquire node-ID',
};

const hex = (value, digits) => `0x${value.toString(16).toUpperCase().padStart(digits, '0')}`;

/** The bytes of a hex string ("0102AB"); [] for an empty one. */
export function bytesOf(data) {
  const bytes = [];
  for (let i = 0; i + 1 < (data || '').length; i += 2) bytes.push(parseInt(data.slice(i, i + 2), 16));
  return bytes;
}

/** The numeric identifier of a frame's "0x181" (or a number). */
export function idOf(frame) {
  return typeof frame.id === 'number' ? frame.id : parseInt(frame.id, 16);
}

const u16 = (b, at) => b[at] | (b[at + 1] << 8);
const u32 = (b, at) => (b[at] | (b[at + 1] << 8) | (b[at + 2] << 16) | (b[at + 3] << 24)) >>> 0;
const multiplexer = (b) => `${hex(u16(b, 1), 4)}/${b[3]}`;

function bytesText(b) {
  return b.map((x) => x.toString(16).toUpperCase().padStart(2, '0')).join(' ');
}

/** What one abort code means, "0x06020000 object does not exist". */
export function abortText(code) {
  const text = SDO_ABORTS[code];
  return text ? `${hex(code, 8)} ${text}` : hex(code, 8);
}

/**
 * An SDO frame's command (CiA 301 7.2.4.3): `request` true for the client's
 * frame (0x600 + node), false for the server's (0x580 + node). `blockSegment`
 * true when the frame is known to be a segment of a block transfer (those
 * carry no command specifier: only the tracker below can tell).
 */
export function decodeSdo(b, request, blockSegment = false) {
  if (b.length !== 8) return { detail: `malformed: ${b.length} data bytes, an SDO frame has 8`, malformed: true };
  if (blockSegment) {
    const seq = b[0] & 0x7f;
    return { detail: `block segment ${seq}${b[0] & 0x80 ? ', last' : ''}: ${bytesText(b.slice(1))}` };
  }
  const cs = b[0] >> 5;
  const toggle = (b[0] >> 4) & 1;
  if (cs === 4) return { detail: `abort ${multiplexer(b)}: ${abortText(u32(b, 4))}` };
  if (request) {
    switch (cs) {
      case 1: { // initiate download
        const expedited = b[0] & 0x02;
        const sized = b[0] & 0x01;
        if (expedited) {
          const n = sized ? 4 - ((b[0] >> 2) & 3) : 4;
          return { detail: `download ${multiplexer(b)} = ${bytesText(b.slice(4, 4 + n))}` };
        }
        return { detail: `download ${multiplexer(b)}, segmented${sized ? `, ${u32(b, 4)} bytes` : ''}` };
      }
      case 0: { // download segment
        const n = 7 - ((b[0] >> 1) & 7);
        return { detail: `download segment t=${toggle}, ${n} bytes${b[0] & 1 ? ', last' : ''}` };
      }
      case 2: return { detail: `upload ${multiplexer(b)}` };
      case 3: return { detail: `upload segment t=${toggle}` };
      case 5: { // block upload, client side (cs in bits 1-0)
        const sub = b[0] & 3;
        if (sub === 0) return { detail: `block upload ${multiplexer(b)}, ${b[4]} segments per block` };
        if (sub === 3) return { detail: 'block upload start' };
        if (sub === 2) return { detail: `block upload ack ${b[1]}, next ${b[2]} segments` };
        return { detail: 'block upload end' };
      }
      case 6: // block download, client side
        if (b[0] & 1) return { detail: `block download end, ${7 - ((b[0] >> 2) & 7)} bytes in the last segment` };
        return { detail: `block download ${multiplexer(b)}${b[0] & 2 ? `, ${u32(b, 4)} bytes` : ''}` };
      default: return { detail: `unknown command specifier ${cs}`, malformed: true };
    }
  }
  switch (cs) {
    case 3: return { detail: `download ${multiplexer(b)} done` };
    case 1: return { detail: `download segment t=${toggle} done` };
    case 2: {
      const expedited = b[0] & 0x02;
      const sized = b[0] & 0x01;
      if (expedited) {
        const n = sized ? 4 - ((b[0] >> 2) & 3) : 4;
        return { detail: `upload ${multiplexer(b)} = ${bytesText(b.slice(4, 4 + n))}` };
      }
      return { detail: `upload ${multiplexer(b)}, segmented${sized ? `, ${u32(b, 4)} bytes` : ''}` };
    }
    case 0: {
      const n = 7 - ((b[0] >> 1) & 7);
      return { detail: `upload segment t=${toggle}, ${n} bytes${b[0] & 1 ? ', last' : ''}` };
    }
    case 5: { // block download, server side
      const sub = b[0] & 3;
      if (sub === 0) return { detail: `block download ${multiplexer(b)} ready, ${b[4]} segments per block` };
      if (sub === 2) return { detail: `block download ack ${b[1]}, next ${b[2]} segments` };
      return { detail: 'block download end done' };
    }
    case 6: // block upload, server side
      if (b[0] & 1) return { detail: `block upload end, ${7 - ((b[0] >> 2) & 7)} bytes in the last segment` };
      return { detail: `block upload ${multiplexer(b)}${b[0] & 2 ? `, ${u32(b, 4)} bytes` : ''}` };
    default: return { detail: `unknown command specifier ${cs}`, malformed: true };
  }
}

function wrongLength(b, wanted) {
  return { detail: `malformed: ${b.length} data bytes, ${wanted}`, malformed: true };
}

function decodeNmt(b) {
  if (b.length !== 2) return wrongLength(b, 'an NMT command has 2');
  const command = NMT_COMMANDS[b[0]] || `command ${hex(b[0], 2)}`;
  return { detail: `${command} ${b[1] === 0 ? 'all nodes' : `node ${b[1]}`}`, malformed: !NMT_COMMANDS[b[0]] || b[1] > 127 };
}

function decodeHeartbeat(frame, b) {
  if (frame.rtr) return { label: 'Guarding', detail: 'node guarding request' };
  if (b.length !== 1) return wrongLength(b, 'a heartbeat has 1');
  const state = NMT_STATES[b[0] & 0x7f];
  if (b[0] & 0x80) {
    return { label: 'Guarding', detail: `${state || `state ${hex(b[0] & 0x7f, 2)}`}, toggle 1`, malformed: !state };
  }
  if (b[0] === 0) return { label: 'Boot-up', detail: 'boot-up' };
  return { detail: state || `state ${hex(b[0], 2)}`, malformed: !state };
}

function decodeEmcy(b) {
  if (b.length === 0) return { detail: 'no data' };
  if (b.length !== 8) return wrongLength(b, 'an EMCY has 8');
  const code = u16(b, 0);
  const manufacturer = b.slice(3).some((x) => x) ? `, manufacturer ${bytesText(b.slice(3))}` : '';
  return { detail: code === 0 ? `error reset, register ${hex(b[2], 2)}` : `${hex(code, 4)}, register ${hex(b[2], 2)}${manufacturer}` };
}

function decodeTime(b) {
  if (b.length !== 6) return wrongLength(b, 'a TIME stamp has 6');
  const ms = u32(b, 0) & 0x0fffffff;
  const days = u16(b, 4);
  // Days since 1984-01-01, ms since midnight.
  const at = new Date(Date.UTC(1984, 0, 1) + days * 86400000 + ms);
  return { detail: at.toISOString().replace('T', ' ').replace('Z', ' UTC') };
}

function decodeLss(b, request) {
  if (b.length !== 8) return wrongLength(b, 'an LSS frame has 8');
  const command = LSS_COMMANDS[b[0]] || `command ${hex(b[0], 2)}`;
  let detail = command;
  if (b[0] === 0x04) detail += b[1] ? ' configuration' : ' waiting';
  else if (b[0] === 0x11 && request) detail += ` ${b[1]}`;
  else if (b[0] >= 0x5a && b[0] <= 0x5d && !request) detail += ` = ${hex(u32(b, 1), 8)}`;
  else if (b[0] === 0x5e && !request) detail += ` = ${b[1]}`;
  else if ((b[0] >= 0x40 && b[0] <= 0x43) || (b[0] >= 0x46 && b[0] <= 0x4b)) detail += ` ${hex(u32(b, 1), 8)}`;
  return { detail };
}

const PDOS = { 0x180: 'TPDO1', 0x200: 'RPDO1', 0x280: 'TPDO2', 0x300: 'RPDO2', 0x380: 'TPDO3', 0x400: 'RPDO3', 0x480: 'TPDO4', 0x500: 'RPDO4' };

/**
 * Decodes one frame. `sdoBlocks` (optional, from sdoBlockTracker) says
 * which SDO frames are block segments; without it every SDO frame is read
 * by its command specifier.
 */
export function decodeFrame(frame, sdoBlocks = null) {
  const b = bytesOf(frame.data);
  const id = idOf(frame);
  const out = (service, label, node, decoded) => ({
    service, label: decoded.label || label, node, detail: decoded.detail || '', malformed: Boolean(decoded.malformed),
  });
  if (frame.error) return out('other', 'Error frame', null, { detail: 'error frame' });
  if (frame.extended) return out('other', 'Extended', null, { detail: '29-bit identifier: not CANopen' });
  if (id === 0x000) return out('nmt', 'NMT', null, decodeNmt(b));
  if (id === 0x080) {
    if (b.length > 1) return out('sync', 'SYNC', null, wrongLength(b, 'a SYNC has 0 or 1'));
    return out('sync', 'SYNC', null, { detail: b.length ? `counter ${b[0]}` : '' });
  }
  if (id === 0x100) return out('time', 'TIME', null, decodeTime(b));
  if (id === 0x7e5) return out('lss', 'LSS request', null, decodeLss(b, true));
  if (id === 0x7e4) return out('lss', 'LSS response', null, decodeLss(b, false));
  const fn = id & 0x780;
  const node = id & 0x7f;
  if (node === 0) return out('other', 'Other', null, {});
  if (fn === 0x080) return out('emcy', 'EMCY', node, decodeEmcy(b));
  if (PDOS[fn]) {
    return out('pdo', PDOS[fn], node, frame.rtr ? { detail: 'remote request' } : { detail: b.length ? `${b.length} bytes` : 'no data' });
  }
  if (fn === 0x580 || fn === 0x600) {
    const request = fn === 0x600;
    const block = sdoBlocks ? sdoBlocks.isSegment(node, request, b) : false;
    return out('sdo', request ? 'SDO request' : 'SDO response', node, decodeSdo(b, request, block));
  }
  if (fn === 0x700) return out('heartbeat', 'Heartbeat', node, decodeHeartbeat(frame, b));
  return out('other', 'Other', node, {});
}

/**
 * Follows SDO block transfers (CiA 301 7.2.4.3.9-16) node by node, to tell
 * their segments, which carry a sequence number where other SDO frames
 * carry a command, from commands. Feed it every SDO frame in bus order
 * (decodeFrame does).
 */
export function sdoBlockTracker() {
  // node -> {sender: 'client'|'server'|null, blksize, last, waiting}
  const transfers = new Map();
  const get = (node) => {
    if (!transfers.has(node)) transfers.set(node, { sender: null, blksize: 0, last: false, waiting: false });
    return transfers.get(node);
  };
  return {
    isSegment(node, request, b) {
      if (b.length !== 8) return false;
      const t = get(node);
      const sending = t.sender === (request ? 'client' : 'server');
      if (sending && !t.waiting) {
        // A segment: the block ends at blksize segments or at the last one.
        if (b[0] & 0x80) t.last = true;
        if (t.last || (b[0] & 0x7f) >= t.blksize) t.waiting = true;
        return true;
      }
      const cs = b[0] >> 5;
      const sub = b[0] & 3;
      if (cs === 4) transfers.delete(node); // an abort ends any transfer
      else if (request && cs === 5 && sub === 0) Object.assign(t, { blksize: b[4], sender: null, last: false, waiting: false });
      else if (request && cs === 5 && sub === 3) Object.assign(t, { sender: 'server', last: false, waiting: false });
      else if (!request && cs === 5 && sub === 0) Object.assign(t, { blksize: b[4], sender: 'client', last: false, waiting: false });
      else if (cs === 5 && sub === 2 && t.waiting && request === (t.sender === 'server')) {
        // The receiver's ack: the next block, or the end frame after the last.
        t.blksize = b[2];
        t.waiting = false;
        if (t.last) t.sender = null;
      }
      return false;
    },
  };
}

/**
 * A list of identifiers and ranges, "181, 0x700-0x77F, 601h", as
 * [[low, high], ...]; numbers are hex (candump writes ids so), with or
 * without 0x / h. Throws an Error naming the part it cannot read.
 */
export function parseIdList(text) {
  return parseList(text, (part) => {
    const digits = part.replace(/^0x/i, '').replace(/h$/i, '');
    if (!/^[0-9a-f]{1,8}$/i.test(digits)) throw new Error(`'${part}' is no hex CAN identifier`);
    const value = parseInt(digits, 16);
    if (value > 0x1fffffff) throw new Error(`'${part}' is beyond 0x1FFFFFFF`);
    return value;
  });
}

/** A list of node ids and ranges, "1, 3-5" (decimal, 1 to 127). */
export function parseNodeList(text) {
  return parseList(text, (part) => {
    if (!/^\d{1,3}$/.test(part) || Number(part) < 1 || Number(part) > 127) throw new Error(`'${part}' is no node id (1 to 127)`);
    return Number(part);
  });
}

function parseList(text, one) {
  const ranges = [];
  for (const raw of text.split(/[,\s]+/)) {
    const part = raw.trim();
    if (!part) continue;
    const dash = part.indexOf('-', 1);
    if (dash > 0) {
      const low = one(part.slice(0, dash));
      const high = one(part.slice(dash + 1));
      if (high < low) throw new Error(`'${part}': the range ends before it starts`);
      ranges.push([low, high]);
    } else {
      const value = one(part);
      ranges.push([value, value]);
    }
  }
  return ranges;
}

/** Whether `value` is in one of `ranges` (an empty list takes everything). */
export function inRanges(ranges, value) {
  if (!ranges.length) return true;
  return ranges.some(([low, high]) => value >= low && value <= high);
}
