//! The CANopen protocol (CiA 301 application layer, CiA 306 device
//! descriptions), without I/O.
//!
//! Every service is a state machine that takes frames and the current time in
//! and gives frames and deadlines out; nothing here reads a clock or touches a
//! bus. The same code serves the gateway (client, master) and the virtual
//! devices (server, slave), and every timeout is testable with a paused clock.
//!
//! # Layout
//!
//! - [`crc32`]: the CRC-32 (IEEE) a CiA 302-3 program download is verified
//!   with (0x1F56).
//! - [`cob`]: node ids, COB-IDs and the predefined connection set (CiA 301 §7.3.3).
//! - [`nmt`]: network management commands and states, boot-up (§7.2.8.3.2).
//! - [`heartbeat`]: heartbeat producer and consumer, node guarding (§7.2.8.3.2).
//! - [`lss`]: layer setting services, master and slave (CiA 305).
//! - [`manager`]: the network manager of CiA 302-2: the expected nodes, each
//!   one's boot-up, error control and supervision, the machine state.
//! - [`sync`]: SYNC producer and consumer with the optional counter (§7.2.5).
//! - [`emcy`]: emergency messages and their texts (§7.2.7).
//! - [`pdo`]: PDO mapping, bit-level packing, communication parameters and
//!   trigger logic (§7.2.2).
//! - [`sdo`]: SDO client and server, expedited, segmented and block transfers,
//!   abort codes (§7.2.4).
//! - [`od`]: object dictionary: data types, access, values and their byte and
//!   JSON encodings (§7.4).
//! - [`eds`]: EDS and DCF files (CiA 306).

use candeck_can as can;

pub mod cob;
pub mod crc32;
pub mod eds;
pub mod emcy;
pub mod heartbeat;
pub mod lss;
pub mod manager;
pub mod nmt;
pub mod od;
pub mod pdo;
pub mod sdo;
pub mod sync;

pub use cob::NodeId;
