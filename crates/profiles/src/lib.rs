//! What a product means: the knowledge of each supported device that the
//! gateway (to drive a real one) and the virtual devices (to be one) share.
//!
//! # Layout
//!
//! - [`alarm`]: what an alarm means on each product: severity, text and
//!   help (the objects to look at), for the gateway's alarm model.
//! - [`builtin`]: the EDS files candeck carries for its products, written from
//!   their manuals (`eds/` in the repository).
//! - [`cia401`]: CiA 401 generic I/O modules: the digital and analogue
//!   input and output objects, their channels and values.
//! - [`cia402`]: the CiA 402 power drive system (states, controlword, modes).
//! - [`jmc`]: JMC CANopen stepper drives: mode numbers, units, controlword
//!   and statusword bits, homing methods.
//! - [`umc`]: UniSwarm UMC motion controllers: axis index offsets, board and
//!   axis objects, Q15.16 and the other units of the manual.
//! - [`watchdog`]: the objects that keep a device safe when its manager
//!   dies, and the values that switch that off.
//! - [`uioled`]: UniSwarm UIO1LED LED strip controllers: segments, effects and
//!   the renderer of the strip's pixels.

use candeck_canopen as canopen;

pub mod alarm;
pub mod cia401;
pub mod cia402;
pub mod jmc;
pub mod uioled;
pub mod umc;
pub mod watchdog;

/// The EDS files candeck carries, written for candeck from each product's
/// manual (the vendors' manuals, which the repository does not carry),
/// embedded in the binary.
pub mod builtin {
    /// UniSwarm UMC1BDS32, two-axis motion controller.
    pub const UMC1BDS32: &str = include_str!("../../../eds/umc1bds32.eds");
    /// UniSwarm UMC1BD90, motion controller.
    pub const UMC1BD90: &str = include_str!("../../../eds/umc1bd90.eds");
    /// UniSwarm UIO1LED, 10-segment LED strip controller.
    pub const UIO1LED: &str = include_str!("../../../eds/uio1led.eds");
    /// candeck io401, the virtual CiA 401 generic I/O module (no vendor's
    /// product: written for candeck).
    pub const IO401: &str = include_str!("../../../eds/io401.eds");
    /// JMC CANopen stepper drive.
    pub const JMC_STEPPER: &str = include_str!("../../../eds/jmc_stepper.eds");
}
