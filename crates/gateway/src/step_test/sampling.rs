//! The step test's own sampling TPDO (issue 32: "samples come at the
//! loop's rate from a TPDO"): for the test's duration one TPDO of the node
//! carries the loop's actual value, event-driven (type 255) on an event
//! timer of 1 ms (the shortest CiA 301's millisecond timer gives, the UMC's
//! control cycle), or longer where that TPDO would take more than a quarter
//! of the bus; then its mapping and communication parameters are put back
//! as they were. Both go through the gateway's PDO procedure
//! ([`NodeHandle::configure_pdo_by_gateway`]: checked against the EDS,
//! followed by the TPDO decoders, one audit row each).
//!
//! The TPDO is a free one (COB-ID bit 31 set) if the node has one, else its
//! last, borrowed. A node that is not operational sends no PDO (CiA 301
//! §7.3.2.2: known from its heartbeats, else from the TPDO not coming), a
//! node without EDS cannot have a mapping checked, a TPDO without event
//! timer cannot be given a rate: the test then reads by SDO and says why.

use serde_json::Value as Json;

use crate::GatewayError;
use crate::can::timing::frame_bits;
use crate::can::{CanId, Frame};
use crate::canopen::nmt::NmtState;
use crate::canopen::pdo::PdoKind;
use crate::node::NodeHandle;
use crate::pdo::{EntryRequest, PdoConfig, PdoRequest};

/// Event-driven, manufacturer- or profile-specific (CiA 301 table 72): sent
/// on the event timer.
const EVENT_DRIVEN: u8 = 255;
/// The most of the bus the sampling TPDO may take.
const BUS_SHARE: f64 = 0.25;

/// A TPDO set up for the test: put back by [`SamplingTpdo::restore`].
pub(crate) struct SamplingTpdo {
    node: NodeHandle,
    /// Its number (1–512).
    pub(crate) number: u16,
    /// Its event timer, ms.
    pub(crate) period_ms: u16,
    /// Its configuration before the test.
    before: PdoConfig,
}

/// How the test samples: its own TPDO, or not and why.
pub(crate) enum Plan {
    Tpdo(Box<SamplingTpdo>),
    Sdo(String),
}

/// Sets up a TPDO of `node` carrying `index` sub 0 (the loop's actual
/// value, at the axis's index) for the test; never fails the test: what
/// stands in the way is said in [`Plan::Sdo`].
pub(crate) async fn set_up(node: &NodeHandle, index: u16) -> Plan {
    match try_set_up(node, index).await {
        Ok(tpdo) => Plan::Tpdo(Box::new(tpdo)),
        Err(why) => Plan::Sdo(why),
    }
}

async fn try_set_up(node: &NodeHandle, index: u16) -> Result<SamplingTpdo, String> {
    let id = node.info.id;
    // The state is current only for a node that sends heartbeats; without
    // them, the last one heard may predate an NMT start: whether the TPDO
    // comes then tells.
    let known = node
        .served
        .registry
        .node(id)
        .filter(|info| info.heartbeat_ms.is_some())
        .and_then(|info| info.nmt);
    if let Some(state) = known.filter(|state| *state != NmtState::Operational) {
        return Err(format!(
            "node {id} is {state} (as last heard): a node sends PDOs only when operational \
             (CiA 301 §7.3.2.2); start it for TPDO sampling"
        ));
    }
    let Some(eds) = node.info.eds_entry.clone() else {
        return Err(format!(
            "node {id} has no EDS: a sampling TPDO's mapping cannot be checked"
        ));
    };
    let bits = eds
        .eds
        .dictionary
        .sub(index, 0)
        .and_then(|sub| sub.data_type.bits())
        .unwrap_or(32);
    let tpdos = node
        .read_tpdos_by_gateway()
        .await
        .map_err(|error| format!("node {id}'s TPDOs could not be read: {error}"))?;
    let before = tpdos
        .iter()
        .find(|config| !config.enabled())
        .or(tpdos.last())
        .cloned()
        .ok_or_else(|| format!("node {id} has no TPDO"))?;
    let number = before.number;
    if before.event_timer_ms.is_none() {
        return Err(format!(
            "TPDO {number} of node {id} has no event timer (its EDS does not describe sub 5): \
             no rate can be set"
        ));
    }
    let period_ms = event_timer_ms(bits, node.served.load().bitrate());
    let request = PdoRequest {
        cob_id: None,
        enabled: Some(true),
        transmission_type: Some(EVENT_DRIVEN),
        inhibit_time_100us: before.inhibit_time_100us.map(|_| 0),
        event_timer_ms: Some(period_ms),
        sync_start: None,
        mapping: Some(vec![EntryRequest {
            index: Json::from(index),
            sub: Some(Json::from(0)),
            bits: None,
        }]),
    };
    let tpdo = SamplingTpdo {
        node: node.clone(),
        number,
        period_ms,
        before,
    };
    let summary = format!(
        "step test sampling: 0x{index:04X} every {period_ms} ms{}",
        if tpdo.before.enabled() {
            " (borrowed, put back after the test)"
        } else {
            ""
        }
    );
    match node
        .configure_pdo_by_gateway(PdoKind::Tpdo, number, &request, summary)
        .await
    {
        Ok(_) => Ok(tpdo),
        Err(error) => {
            // A step may have been taken (the TPDO invalidated): put it back.
            let _ = tpdo.restore().await;
            Err(format!(
                "TPDO {number} of node {id} could not be set up for sampling: {error}"
            ))
        }
    }
}

/// The event timer that sends a TPDO of `bits` data bits at 1 kHz, or
/// slower where that would take more than [`BUS_SHARE`] of a bus of
/// `bitrate` bit/s.
fn event_timer_ms(bits: u32, bitrate: u32) -> u16 {
    let bytes = bits.div_ceil(8).clamp(1, 8) as usize;
    let frame = Frame::new(CanId::Standard(0x181), &[0; 8][..bytes]).map(|f| frame_bits(&f));
    let (Ok(frame), true) = (frame, bitrate > 0) else {
        return 1;
    };
    let shortest_ms = f64::from(frame) * 1000.0 / (f64::from(bitrate) * BUS_SHARE);
    (shortest_ms.ceil() as u16).max(1)
}

impl SamplingTpdo {
    /// Puts the TPDO's mapping and communication parameters back as they
    /// were before the test (its COB-ID's identifier was never changed).
    pub(crate) async fn restore(&self) -> Result<(), GatewayError> {
        let before = &self.before;
        let request = PdoRequest {
            cob_id: None,
            enabled: Some(before.enabled()),
            transmission_type: before.transmission_type,
            inhibit_time_100us: before.inhibit_time_100us,
            event_timer_ms: before.event_timer_ms,
            sync_start: before.sync_start,
            mapping: Some(
                before
                    .mapping
                    .iter()
                    .map(|entry| EntryRequest {
                        index: Json::from(entry.index),
                        sub: Some(Json::from(entry.sub)),
                        bits: Some(u32::from(entry.bits)),
                    })
                    .collect(),
            ),
        };
        let summary = format!(
            "step test sampling over: TPDO {} put back as before the test",
            self.number
        );
        self.node
            .configure_pdo_by_gateway(PdoKind::Tpdo, self.number, &request, summary)
            .await
            .map(|_| ())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_event_timer_is_one_millisecond_unless_the_bus_is_too_slow() {
        // 0x6044 (16 bits) at 500 kbit/s: 75 bits, 15 % of the bus.
        assert_eq!(event_timer_ms(16, 500_000), 1);
        // 0x6064 (32 bits): 95 bits a frame; 1 kHz is 38 % of 250 kbit/s.
        assert_eq!(event_timer_ms(32, 1_000_000), 1);
        assert_eq!(event_timer_ms(32, 250_000), 2);
        assert_eq!(event_timer_ms(32, 125_000), 4);
        assert_eq!(event_timer_ms(16, 0), 1);
    }
}
