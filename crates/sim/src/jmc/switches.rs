//! The three switches of the JMC's homing mode ("In homing mode, we will go
//! back to homing operation through three limit switches, namely CW limit,
//! CCW limit, and origin limit"), placed on the simulated machine; the
//! statusword shows them in bits 14, 15 and 11.
//!
//! Positions are the machine's steps ([`super::axis::Axis::position`]): a
//! switch stays where it is bolted when the drive's position counter is
//! reset or re-zeroed by homing. The CW limit switch is at the left
//! (negative) end and is on from its position leftwards, the CCW one at the
//! right end and on from its position rightwards; the origin switch is a
//! cam, on between its two edges.

use crate::profiles::jmc::Direction;

/// Where the switches are, in machine steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LimitSwitches {
    /// On at and left of this position; `None`: no CW switch fitted.
    pub cw_limit: Option<i64>,
    /// On at and right of this position; `None`: no CCW switch fitted.
    pub ccw_limit: Option<i64>,
    /// On from the first to the second position (inclusive); `None`: no
    /// origin switch fitted (it is optional).
    pub origin: Option<(i64, i64)>,
}

impl Default for LimitSwitches {
    /// A machine whose drive powers up 10 revolutions (of 10 000 steps)
    /// right of the CW end, the origin cam 0.2 revolutions wide half way,
    /// and room for 300 revolutions to the right: the manual's position
    /// routine (2 600 000 steps) fits, and its homing routine (method 1 at
    /// 1 rps) ends in 10 s.
    fn default() -> Self {
        LimitSwitches {
            cw_limit: Some(-100_000),
            ccw_limit: Some(3_000_000),
            origin: Some((-51_000, -49_000)),
        }
    }
}

/// One of the three switches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Switch {
    Cw,
    Ccw,
    Origin,
}

impl Switch {
    /// The limit switch at the end `direction` runs to.
    pub fn limit_towards(direction: Direction) -> Switch {
        match direction {
            Direction::Left => Switch::Cw,
            Direction::Right => Switch::Ccw,
        }
    }
}

impl LimitSwitches {
    /// Whether `switch` is on with the shaft at `position`.
    pub fn is_on(&self, switch: Switch, position: f64) -> bool {
        match switch {
            Switch::Cw => self.cw_limit.is_some_and(|at| position <= at as f64),
            Switch::Ccw => self.ccw_limit.is_some_and(|at| position >= at as f64),
            Switch::Origin => self
                .origin
                .is_some_and(|(from, to)| (from as f64..=to as f64).contains(&position)),
        }
    }

    /// The edge of `switch` a shaft running from `from` to `to` reaches
    /// first where the switch comes on, if it does on the way (a switch
    /// already on at `from` is not reached again).
    pub fn reached(&self, switch: Switch, from: f64, to: f64) -> Option<f64> {
        if self.is_on(switch, from) || !self.is_on(switch, to) && !self.crosses(switch, from, to) {
            return None;
        }
        let edge = match switch {
            Switch::Cw => self.cw_limit? as f64,
            Switch::Ccw => self.ccw_limit? as f64,
            Switch::Origin => {
                let (low, high) = self.origin?;
                if to > from { low as f64 } else { high as f64 }
            }
        };
        Some(edge)
    }

    /// Whether the shaft at `position` is off `switch` on its `direction`
    /// side (right of the CW switch, left of the CCW one, beyond the
    /// origin cam's edge on that side).
    pub fn is_past(&self, switch: Switch, direction: Direction, position: f64) -> bool {
        let edge = match (switch, direction) {
            (Switch::Cw, Direction::Right) => self.cw_limit,
            (Switch::Ccw, Direction::Left) => self.ccw_limit,
            (Switch::Origin, Direction::Left) => self.origin.map(|(low, _)| low),
            (Switch::Origin, Direction::Right) => self.origin.map(|(_, high)| high),
            // The limit switches reach to the ends of the machine.
            (Switch::Cw, Direction::Left) | (Switch::Ccw, Direction::Right) => return false,
        };
        edge.is_some_and(|edge| match direction {
            Direction::Left => position < edge as f64,
            Direction::Right => position > edge as f64,
        })
    }

    /// Whether a run from `from` to `to` goes over the whole origin cam
    /// (on at neither end).
    fn crosses(&self, switch: Switch, from: f64, to: f64) -> bool {
        match (switch, self.origin) {
            (Switch::Origin, Some((low, high))) => {
                let (a, b) = if from < to { (from, to) } else { (to, from) };
                a < low as f64 && b > high as f64
            }
            _ => false,
        }
    }

    /// The statusword bits 11, 14, 15 for the shaft at `position`.
    pub fn status_bits(&self, position: f64) -> u16 {
        use crate::profiles::jmc::{SW_CCW_LIMIT, SW_CW_LIMIT, SW_ORIGIN_SWITCH};
        let bit = |on: bool, mask: u16| if on { mask } else { 0 };
        bit(self.is_on(Switch::Cw, position), SW_CW_LIMIT)
            | bit(self.is_on(Switch::Ccw, position), SW_CCW_LIMIT)
            | bit(self.is_on(Switch::Origin, position), SW_ORIGIN_SWITCH)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn switches_are_on_over_their_zones() {
        let switches = LimitSwitches::default();
        assert!(switches.is_on(Switch::Cw, -100_000.0));
        assert!(switches.is_on(Switch::Cw, -200_000.0));
        assert!(!switches.is_on(Switch::Cw, -99_999.5));
        assert!(switches.is_on(Switch::Ccw, 3_000_000.0));
        assert!(!switches.is_on(Switch::Ccw, 0.0));
        assert!(switches.is_on(Switch::Origin, -50_000.0));
        assert!(!switches.is_on(Switch::Origin, -48_999.0));
        assert_eq!(switches.status_bits(0.0), 0);
        assert_eq!(switches.status_bits(-50_000.0), 1 << 11);
        assert_eq!(switches.status_bits(-100_001.0), 1 << 14);
        let none = LimitSwitches {
            cw_limit: None,
            ccw_limit: None,
            origin: None,
        };
        assert_eq!(none.status_bits(-1e9), 0);
    }

    #[test]
    fn the_edge_reached_depends_on_the_direction() {
        let switches = LimitSwitches::default();
        assert_eq!(
            switches.reached(Switch::Origin, -48_000.0, -49_500.0),
            Some(-49_000.0)
        );
        assert_eq!(
            switches.reached(Switch::Origin, -52_000.0, -50_500.0),
            Some(-51_000.0)
        );
        // Jumped over in one tick: still reached.
        assert_eq!(
            switches.reached(Switch::Origin, -48_000.0, -53_000.0),
            Some(-49_000.0)
        );
        assert_eq!(switches.reached(Switch::Origin, -50_000.0, -50_100.0), None);
        assert_eq!(
            switches.reached(Switch::Cw, -99_990.0, -100_010.0),
            Some(-100_000.0)
        );
        assert_eq!(switches.reached(Switch::Cw, -99_990.0, -99_995.0), None);
        assert!(switches.is_past(Switch::Origin, Direction::Right, -48_999.0));
        assert!(!switches.is_past(Switch::Origin, Direction::Right, -49_000.0));
        assert!(switches.is_past(Switch::Origin, Direction::Left, -51_001.0));
        assert!(!switches.is_past(Switch::Origin, Direction::Left, -40_000.0));
        assert!(switches.is_past(Switch::Cw, Direction::Right, -99_999.0));
        assert!(!switches.is_past(Switch::Cw, Direction::Left, -200_000.0));
        assert!(switches.is_past(Switch::Ccw, Direction::Left, 0.0));
    }
}
