//! Fault confinement of a CAN controller (ISO 11898-1 §12 "fault
//! confinement"; the states as CiA 301 names them in its EMCY codes 0x8120
//! "CAN in error passive mode" and 0x8140 "recovered from bus-off").
//!
//! Sans-I/O like the rest of the layer: the owner says what happened on the
//! wire (a transmission failed or succeeded, a reception failed or
//! succeeded, so many recessive bits went by) and gets back the state
//! transition, if any. Nothing here reads a clock.
//!
//! The rules kept (ISO 11898-1 §12.1.4):
//!
//! - Two counters, the transmit error counter (TEC) and the receive error
//!   counter (REC). A transmitter that detects an error adds 8 to its TEC, a
//!   receiver 1 to its REC; a successful transmission takes 1 from the TEC, a
//!   successful reception 1 from the REC, or brings a REC above 127 back to a
//!   value between 119 and 127 (we use 127, the first the standard allows).
//! - Error active while both counters are below 128; error passive when
//!   either is 128 or more; bus-off when the TEC passes 255. The REC alone
//!   never makes a node bus-off.
//! - A bus-off node takes no part in the bus: it neither sends nor
//!   acknowledges. It becomes error active again, both counters 0, after
//!   128 occurrences of 11 consecutive recessive bits; the count starts when
//!   the host asks for the recovery ([`BusOffRecovery::OnRequest`], as
//!   ISO 11898-1:2015 has it, and as most CANopen devices are set up), or at
//!   once ([`BusOffRecovery::Automatic`], the older controllers' behaviour
//!   and Linux's `restart-ms`).

use std::fmt;

/// The error states of a CAN controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ErrorState {
    /// Both counters below 128: the node sends active error flags.
    #[default]
    ErrorActive,
    /// A counter at 128 or more: the node still sends and receives, but
    /// signals errors passively and waits longer between its frames.
    ErrorPassive,
    /// The TEC passed 255: the node is off the bus.
    BusOff,
}

impl ErrorState {
    /// The name in the HTTP API and the metrics: `error_active`,
    /// `error_passive`, `bus_off`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::ErrorActive => "error_active",
            Self::ErrorPassive => "error_passive",
            Self::BusOff => "bus_off",
        }
    }

    /// The state two counters mean (a TEC above 255 is bus-off).
    pub fn of_counters(tec: u16, rec: u16) -> Self {
        if tec > BUS_OFF_LIMIT {
            Self::BusOff
        } else if tec >= PASSIVE_LIMIT || rec >= PASSIVE_LIMIT {
            Self::ErrorPassive
        } else {
            Self::ErrorActive
        }
    }
}

impl fmt::Display for ErrorState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A counter at this value or above makes the node error passive.
pub const PASSIVE_LIMIT: u16 = 128;
/// A TEC above this value makes the node bus-off.
pub const BUS_OFF_LIMIT: u16 = 255;
/// What a transmitter adds to its TEC for an error it detects.
pub const TX_ERROR_STEP: u16 = 8;
/// Occurrences of [`RECESSIVE_RUN`] recessive bits a bus-off node waits for.
pub const RECOVERY_RUNS: u64 = 128;
/// Consecutive recessive bits that make one occurrence.
pub const RECESSIVE_RUN: u64 = 11;
/// The bit times a bus-off recovery takes on an idle bus: 128 × 11.
pub const RECOVERY_BITS: u64 = RECOVERY_RUNS * RECESSIVE_RUN;

/// When a bus-off node starts its recovery.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BusOffRecovery {
    /// When the host asks ([`FaultConfinement::request_recovery`]).
    #[default]
    OnRequest,
    /// As soon as it is bus-off.
    Automatic,
}

/// A change of error state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Transition {
    pub from: ErrorState,
    pub to: ErrorState,
}

/// The counters and state of one controller, copied at one moment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ControllerStatus {
    pub state: ErrorState,
    /// Transmit error counter (above 255 only while bus-off).
    pub tec: u16,
    /// Receive error counter.
    pub rec: u16,
}

/// The fault confinement of one controller. See the module documentation.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct FaultConfinement {
    tec: u16,
    rec: u16,
    bus_off: bool,
    recovery: BusOffRecovery,
    /// While bus-off with a recovery under way: the recessive bits seen so
    /// far.
    recessive_bits: Option<u64>,
}

impl FaultConfinement {
    /// An error-active controller, counters 0, that recovers from bus-off
    /// on request.
    pub fn new() -> Self {
        Self::default()
    }

    /// An error-active controller with the given bus-off recovery.
    pub fn with_recovery(recovery: BusOffRecovery) -> Self {
        Self {
            recovery,
            ..Self::default()
        }
    }

    pub fn state(&self) -> ErrorState {
        if self.bus_off {
            ErrorState::BusOff
        } else {
            ErrorState::of_counters(self.tec, self.rec)
        }
    }

    pub fn tec(&self) -> u16 {
        self.tec
    }

    pub fn rec(&self) -> u16 {
        self.rec
    }

    pub fn status(&self) -> ControllerStatus {
        ControllerStatus {
            state: self.state(),
            tec: self.tec,
            rec: self.rec,
        }
    }

    /// Whether the controller may send (it is not bus-off).
    pub fn can_transmit(&self) -> bool {
        !self.bus_off
    }

    /// Whether a bus-off recovery is counting recessive bits.
    pub fn recovering(&self) -> bool {
        self.recessive_bits.is_some()
    }

    /// Recessive bits still needed to end a recovery under way.
    pub fn recovery_bits_left(&self) -> Option<u64> {
        self.recessive_bits
            .map(|seen| RECOVERY_BITS.saturating_sub(seen))
    }

    /// The controller detected an error in a frame it was sending: TEC + 8.
    pub fn transmit_error(&mut self) -> Option<Transition> {
        self.change(|me| {
            if me.bus_off {
                return;
            }
            me.tec = me.tec.saturating_add(TX_ERROR_STEP);
            if me.tec > BUS_OFF_LIMIT {
                me.bus_off = true;
                if me.recovery == BusOffRecovery::Automatic {
                    me.recessive_bits = Some(0);
                }
            }
        })
    }

    /// A frame sent without error: TEC − 1.
    pub fn transmit_ok(&mut self) -> Option<Transition> {
        self.change(|me| {
            if !me.bus_off {
                me.tec = me.tec.saturating_sub(1);
            }
        })
    }

    /// The controller detected an error in a frame it was receiving: REC + 1.
    pub fn receive_error(&mut self) -> Option<Transition> {
        self.change(|me| {
            if !me.bus_off {
                // The REC cannot make a node bus-off; it is reported in a
                // byte (SocketCAN's data[7]), so it stops at 255.
                me.rec = (me.rec + 1).min(255);
            }
        })
    }

    /// A frame received without error: REC − 1, or back to 127 from above.
    pub fn receive_ok(&mut self) -> Option<Transition> {
        self.change(|me| {
            if me.bus_off {
                return;
            }
            me.rec = if me.rec >= PASSIVE_LIMIT {
                PASSIVE_LIMIT - 1
            } else {
                me.rec.saturating_sub(1)
            };
        })
    }

    /// Off the bus at once (a fault that takes the node bus-off: the TEC is
    /// set past 255, as the errors that cause it would have).
    pub fn force_bus_off(&mut self) -> Option<Transition> {
        self.change(|me| {
            if me.bus_off {
                return;
            }
            me.tec = BUS_OFF_LIMIT + 1;
            me.bus_off = true;
            if me.recovery == BusOffRecovery::Automatic {
                me.recessive_bits = Some(0);
            }
        })
    }

    /// The host asks a bus-off controller to recover: it counts recessive
    /// bits from now on. Nothing happens in the other states, or when a
    /// recovery is already under way.
    pub fn request_recovery(&mut self) {
        if self.bus_off && self.recessive_bits.is_none() {
            self.recessive_bits = Some(0);
        }
    }

    /// `bits` recessive bit times went by (an idle bus; on a busy bus each
    /// frame's ACK delimiter, end of frame and intermission are one run of
    /// 11). After [`RECOVERY_BITS`] of them a recovering node is error
    /// active again, both counters 0.
    pub fn recessive_bits(&mut self, bits: u64) -> Option<Transition> {
        self.change(|me| {
            let Some(seen) = me.recessive_bits.as_mut() else {
                return;
            };
            *seen = seen.saturating_add(bits);
            if *seen >= RECOVERY_BITS {
                me.recessive_bits = None;
                me.bus_off = false;
                me.tec = 0;
                me.rec = 0;
            }
        })
    }

    fn change(&mut self, f: impl FnOnce(&mut Self)) -> Option<Transition> {
        let from = self.state();
        f(self);
        let to = self.state();
        (from != to).then_some(Transition { from, to })
    }
}

#[cfg(test)]
mod tests;
