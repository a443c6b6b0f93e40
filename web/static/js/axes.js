// Faults per axis: which of a node's EMCYs belong to which axis. The
// gateway tags each EMCY with the axis its product says it belongs to
// (`axis`, null for the whole node: the UMC puts the axis in the first
// manufacturer byte); an axis's own history is its EMCYs and the node's.

import { isFault } from './cia402.js';

/** The EMCYs of the node that concern `axis`, oldest first. */
export function axisEmcys(detail, axis) {
  const list = (detail && detail.emcy) || [];
  return list.filter((e) => e.axis === null || e.axis === undefined || e.axis === Number(axis));
}

/** Whether an EMCY is an error reset (CiA 301: 0x00xx, the errors are gone). */
export const isReset = (emcy) => /^0x00/i.test(emcy.code);

/**
 * An axis's fault as the page says it: `faulted` from its own state (its
 * statusword), `cause` its newest EMCY that is not a reset (the reason of
 * a fault), `last` its newest EMCY of all.
 */
export function axisFault(detail, status) {
  const axis = status ? status.axis : null;
  const own = axis === null || axis === undefined ? [] : axisEmcys(detail, axis);
  const faulted = Boolean(status && (isFault(status.state) || status.fault === true));
  const causes = own.filter((e) => !isReset(e));
  return {
    faulted,
    cause: causes.length ? causes[causes.length - 1] : null,
    last: own.length ? own[own.length - 1] : null,
  };
}
