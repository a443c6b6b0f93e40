//! Linux SocketCAN (`Documentation/networking/can.rst`), through the
//! `socketcan` crate (imported as `socketcan_rs`).
//!
//! Always compiled, because the candump log code needs them too:
//! - [`to_socketcan`] / [`from_socketcan`]: our [`Frame`] and the crate's
//!   [`CanAnyFrame`] (`struct can_frame` / `struct canfd_frame`), both ways;
//! - [`bus_state_after_error`]: what an error frame (`CAN_ERR_FLAG`,
//!   `linux/can/error.h`) says about the controller's state, and
//!   [`error_frame_report`], that with the error counters it carries: the
//!   same events the virtual hub's fault confinement gives.
//!
//! Behind the `socketcan` cargo feature: `open_socketcan`, a [`Bus`](crate::Bus)
//! on a CAN network interface (`can0`, `vcan0`, ...).

use socketcan_rs::errors::{CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_RESTARTED, ControllerProblems};
use socketcan_rs::frame::{can_frame_default, canfd_frame_default};
use socketcan_rs::id::{CAN_EFF_FLAG, CAN_EFF_MASK, CAN_ERR_FLAG, CAN_RTR_FLAG, CAN_SFF_MASK};
use socketcan_rs::{CanAnyFrame, CanFdFrame, CanFrame, EmbeddedFrame, Frame as _};

use super::bus::{BusState, BusStatus};
use super::frame::{CanId, ERROR_FRAME_LEN, FdFlags, Frame, FrameError, FrameKind};

/// The SocketCAN form of a frame. Never fails: every [`Frame`] is a frame
/// the kernel accepts. FD frames get `CANFD_FDF` set, as the kernel does.
pub fn to_socketcan(frame: &Frame) -> CanAnyFrame {
    let id_word = match frame.id() {
        CanId::Standard(id) => u32::from(id),
        CanId::Extended(id) => id | CAN_EFF_FLAG,
    };
    let data = frame.data();
    match frame.kind() {
        FrameKind::Fd(flags) => {
            let mut raw = canfd_frame_default();
            let len = data.len().min(raw.data.len());
            raw.can_id = id_word;
            raw.len = len as u8;
            raw.flags = flags.raw();
            raw.data[..len].copy_from_slice(&data[..len]);
            CanAnyFrame::Fd(CanFdFrame::from(raw))
        }
        kind => {
            let mut raw = can_frame_default();
            let len = data.len().min(raw.data.len());
            raw.can_id = match kind {
                // The class bits travel without CAN_EFF_FLAG, as the kernel sends them.
                FrameKind::Error => frame.id().raw() | CAN_ERR_FLAG,
                FrameKind::Remote => id_word | CAN_RTR_FLAG,
                _ => id_word,
            };
            raw.can_dlc = frame.dlc();
            raw.data[..len].copy_from_slice(&data[..len]);
            CanAnyFrame::from(CanFrame::from(raw))
        }
    }
}

/// Our form of a SocketCAN frame. Fails only on what a [`Frame`] cannot hold
/// (an FD length no DLC expresses); the crate's own types already rule that
/// out, so in practice this succeeds.
pub fn from_socketcan(frame: &CanAnyFrame) -> Result<Frame, FrameError> {
    match frame {
        CanAnyFrame::Normal(data) => Frame::new(id_from_word(data.id_word()), data.data()),
        CanAnyFrame::Remote(remote) => {
            let dlc = u8::try_from(remote.dlc()).unwrap_or(u8::MAX);
            Frame::remote(id_from_word(remote.id_word()), dlc)
        }
        CanAnyFrame::Error(error) => {
            let mut details = [0u8; ERROR_FRAME_LEN];
            let bytes = error.data();
            let len = bytes.len().min(ERROR_FRAME_LEN);
            details[..len].copy_from_slice(&bytes[..len]);
            Frame::error(error.error_bits(), details)
        }
        CanAnyFrame::Fd(fd) => {
            // The raw flag byte, not `fd.flags()`: that getter drops bits it has
            // no name for, and we want exactly what the kernel delivered.
            let flags = FdFlags::from_raw(fd.as_ref().flags);
            Frame::fd(id_from_word(fd.id_word()), fd.data(), flags)
        }
    }
}

/// The identifier in a SocketCAN `can_id` word: the format comes from
/// `CAN_EFF_FLAG`, never from the value.
fn id_from_word(word: u32) -> CanId {
    if word & CAN_EFF_FLAG != 0 {
        CanId::Extended(word & CAN_EFF_MASK)
    } else {
        CanId::Standard((word & CAN_SFF_MASK) as u16)
    }
}

/// The bus state an error frame moves a controller to, with a reason for
/// people, or `None` when the frame changes nothing (not an error frame, a
/// class that says nothing about the state, or a state already reached).
///
/// Read from the class bits of `linux/can/error.h`: `CAN_ERR_BUSOFF` (0x40),
/// `CAN_ERR_RESTARTED` (0x100) and `CAN_ERR_CRTL` (0x04) with the controller
/// status in `data[1]` (`CAN_ERR_CRTL_RX_WARNING` 0x04, `TX_WARNING` 0x08,
/// `RX_PASSIVE` 0x10, `TX_PASSIVE` 0x20, `ACTIVE` 0x40). When one frame
/// reports several, the most severe wins, so a contradictory frame never
/// makes a bus look healthier than it is.
///
/// A bus that is [`BusState::Down`] stays down: error frames speak about the
/// controller, not about whether the interface is there, and only the driver
/// that lost the interface may bring it back.
pub fn bus_state_after_error(frame: &Frame, current: BusState) -> Option<BusStatus> {
    let class = frame.error_class()?;
    if current == BusState::Down {
        return None;
    }
    let (state, reason) = if class & CAN_ERR_BUSOFF != 0 {
        (
            BusState::BusOff,
            "controller is bus-off (too many transmit errors)".to_string(),
        )
    } else if class & CAN_ERR_RESTARTED != 0 {
        (
            BusState::Up,
            "controller restarted after bus-off".to_string(),
        )
    } else if class & CAN_ERR_CRTL != 0 {
        let status = frame.data().get(1).copied().unwrap_or(0);
        controller_status(ControllerProblems::from_bits_retain(status))?
    } else {
        return None;
    };
    (state != current).then(|| BusStatus::new(state, reason))
}

/// `CAN_ERR_CNT` of `linux/can/error.h`: data\[6\] holds the transmit error
/// counter, data\[7\] the receive error counter.
pub const CAN_ERR_CNT: u32 = 0x200;

/// The error counters an error frame carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ErrorCounters {
    pub tec: u8,
    pub rec: u8,
}

/// What one error frame tells about the controller.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ErrorFrameReport {
    /// The new status, as [`bus_state_after_error`] gives it.
    pub status: Option<BusStatus>,
    /// The counters, when the frame has them: with `CAN_ERR_CNT` (0x200),
    /// and with `CAN_ERR_CRTL`, where drivers wrote them before the flag
    /// existed; 0 and 0 after `CAN_ERR_RESTARTED` (a restarted controller
    /// starts afresh) unless the frame says otherwise.
    pub counters: Option<ErrorCounters>,
}

/// Reads an error frame (`CAN_ERR_FLAG`) as the events of the bus: state
/// and counters. Not an error frame: nothing.
pub fn error_frame_report(frame: &Frame, current: BusState) -> ErrorFrameReport {
    let Some(class) = frame.error_class() else {
        return ErrorFrameReport::default();
    };
    let data = frame.data();
    let counters = if class & (CAN_ERR_CNT | CAN_ERR_CRTL) != 0 {
        Some(ErrorCounters {
            tec: data.get(6).copied().unwrap_or(0),
            rec: data.get(7).copied().unwrap_or(0),
        })
    } else if class & CAN_ERR_RESTARTED != 0 {
        Some(ErrorCounters { tec: 0, rec: 0 })
    } else {
        None
    };
    ErrorFrameReport {
        status: bus_state_after_error(frame, current),
        counters,
    }
}

/// The state named by the controller status byte of a `CAN_ERR_CRTL` frame.
/// Warning levels are still error active, so they mean [`BusState::Up`]: the
/// kernel reports them when a controller comes back down from passive.
fn controller_status(status: ControllerProblems) -> Option<(BusState, String)> {
    let which = |tx: ControllerProblems, rx: ControllerProblems| match (
        status.contains(tx),
        status.contains(rx),
    ) {
        (true, true) => "transmit and receive errors",
        (true, false) => "transmit errors",
        _ => "receive errors",
    };
    if status.intersects(ControllerProblems::TX_PASSIVE | ControllerProblems::RX_PASSIVE) {
        let errors = which(
            ControllerProblems::TX_PASSIVE,
            ControllerProblems::RX_PASSIVE,
        );
        return Some((
            BusState::ErrorPassive,
            format!("controller is error passive ({errors})"),
        ));
    }
    if status.contains(ControllerProblems::ACTIVE) {
        return Some((BusState::Up, "controller is error active again".to_string()));
    }
    if status.intersects(ControllerProblems::TX_WARNING | ControllerProblems::RX_WARNING) {
        let errors = which(
            ControllerProblems::TX_WARNING,
            ControllerProblems::RX_WARNING,
        );
        return Some((
            BusState::Up,
            format!("controller is error active at warning level ({errors})"),
        ));
    }
    None
}

#[cfg(feature = "socketcan")]
pub use driver::{RECONNECT_INTERVAL, SocketcanError, open_socketcan};

#[cfg(feature = "socketcan")]
mod driver {
    //! The driver task: one raw CAN socket, read and written from one task,
    //! reopened while the interface is gone.

    use std::io;
    use std::time::Duration;

    use socketcan_rs::tokio::{CanFdSocket, CanSocket};
    use socketcan_rs::{CanAnyFrame, CanFrame, CanTimestamps, SocketOptions};
    use tokio::time::Instant;

    use super::{error_frame_report, from_socketcan, to_socketcan};
    use crate::bus::{
        Bus, BusCounters, BusKind, BusState, BusStatus, DriverSide, attach_driver, driver_channels,
    };
    use crate::frame::{Frame, Timestamp};

    /// How often a lost interface is looked for again.
    pub const RECONNECT_INTERVAL: Duration = Duration::from_secs(1);

    /// `ENODEV` on Linux (`asm-generic/errno-base.h`): the interface was
    /// removed. std has no stable `ErrorKind` for it.
    const ENODEV: i32 = 19;
    /// `ENXIO` on Linux: the device behind the interface is gone.
    const ENXIO: i32 = 6;
    /// `IFF_UP` of `linux/if.h`, in `/sys/class/net/IFACE/flags`.
    const IFF_UP: u32 = 0x1;

    /// Why a SocketCAN bus could not be opened.
    #[derive(Debug, thiserror::Error)]
    pub enum SocketcanError {
        #[error("cannot open SocketCAN interface {iface}: {source}")]
        Open {
            iface: String,
            #[source]
            source: io::Error,
        },
    }

    /// Opens the CAN network interface `iface` (`can0`, `vcan0`, ...) as a
    /// bus named after it, with spec `socketcan:IFACE`. Must run inside a
    /// tokio runtime.
    ///
    /// The socket is FD-capable when the kernel allows, else classic. It
    /// receives every error class, so bus-off and error-passive show in the
    /// bus status. If the interface goes away later (down, unplugged), the
    /// bus turns [`BusState::Down`] with the reason and the interface is
    /// looked for every [`RECONNECT_INTERVAL`] until it is back.
    pub async fn open_socketcan(iface: &str) -> Result<Bus, SocketcanError> {
        let socket = Socket::open(iface).map_err(|source| SocketcanError::Open {
            iface: iface.to_string(),
            source,
        })?;
        // A socket binds to an interface that is down without complaint, and
        // then stays silent: report that rather than an idle bus that is "up".
        let (initial, socket) = if interface_is_up(iface) == Some(false) {
            (down_status(iface, "interface is down"), None)
        } else {
            (BusStatus::up(), Some(socket))
        };
        let spec = format!("socketcan:{iface}");
        let (parts, driver) = driver_channels(iface, &spec, BusKind::Socketcan, initial, false);
        let task = tokio::spawn(run(iface.to_string(), socket, driver));
        Ok(attach_driver(parts, task))
    }

    fn down_status(iface: &str, what: impl std::fmt::Display) -> BusStatus {
        BusStatus::new(BusState::Down, format!("{iface}: {what}"))
    }

    /// Whether `iface` is administratively up, from sysfs; `None` when sysfs
    /// cannot tell (then the socket calls are the only judge).
    fn interface_is_up(iface: &str) -> Option<bool> {
        if iface.is_empty() || iface.contains('/') || iface.starts_with('.') {
            return None;
        }
        let text = std::fs::read_to_string(format!("/sys/class/net/{iface}/flags")).ok()?;
        let hex = text.trim().trim_start_matches("0x");
        let flags = u32::from_str_radix(hex, 16).ok()?;
        Some(flags & IFF_UP != 0)
    }

    /// The raw CAN socket, FD-capable when the kernel allows.
    enum Socket {
        Fd(CanFdSocket),
        Classic(CanSocket),
    }

    impl Socket {
        fn open(iface: &str) -> io::Result<Self> {
            let socket = match CanFdSocket::open(iface) {
                Ok(socket) => Self::Fd(socket),
                // Kernels without CAN_RAW_FD_FRAMES refuse the FD socket
                // option; a classic socket still serves classic frames.
                Err(fd_error) => match CanSocket::open(iface) {
                    Ok(socket) => Self::Classic(socket),
                    Err(_) => return Err(fd_error),
                },
            };
            socket.configure(iface);
            Ok(socket)
        }

        fn configure(&self, iface: &str) {
            match self {
                Self::Fd(socket) => configure(socket, iface),
                Self::Classic(socket) => configure(socket, iface),
            }
        }

        /// The next frame with the kernel's receive time when it gave one.
        async fn read(&self) -> io::Result<(CanAnyFrame, CanTimestamps)> {
            match self {
                Self::Fd(socket) => socket.read_frame_with_timestamps().await,
                Self::Classic(socket) => socket
                    .read_frame_with_timestamps()
                    .await
                    .map(|(frame, ts)| (CanAnyFrame::from(frame), ts)),
            }
        }

        async fn write(&self, frame: &Frame) -> io::Result<()> {
            let raw = to_socketcan(frame);
            match self {
                Self::Fd(socket) => socket.write_frame(&raw).await,
                Self::Classic(socket) => {
                    let classic = match raw {
                        CanAnyFrame::Normal(f) => CanFrame::Data(f),
                        CanAnyFrame::Remote(f) => CanFrame::Remote(f),
                        CanAnyFrame::Error(f) => CanFrame::Error(f),
                        CanAnyFrame::Fd(_) => {
                            return Err(io::Error::new(
                                io::ErrorKind::Unsupported,
                                "this kernel's CAN sockets carry classic frames only, not CAN FD",
                            ));
                        }
                    };
                    socket.write_frame(classic).await
                }
            }
        }
    }

    fn configure(options: &impl SocketOptions, iface: &str) {
        // Without error frames a bus-off controller would look like a quiet
        // bus.
        if let Err(err) = options.set_error_filter_accept_all() {
            tracing::warn!(%iface, %err, "cannot receive CAN error frames; bus state will not follow the controller");
        }
        if let Err(err) = options.set_recv_timestamp(true) {
            tracing::warn!(%iface, %err, "no kernel receive timestamps; using the time frames are read");
        }
    }

    /// Whether an I/O error means the interface itself is gone or down.
    fn interface_gone(err: &io::Error) -> bool {
        matches!(
            err.kind(),
            io::ErrorKind::NetworkDown | io::ErrorKind::NotFound
        ) || matches!(err.raw_os_error(), Some(ENODEV | ENXIO))
    }

    /// How a connected session ended.
    enum Ended {
        /// The interface went away; the reason, for the status.
        Lost(String),
        /// Every handle to the bus is gone.
        Closed,
    }

    async fn run(iface: String, mut socket: Option<Socket>, mut driver: DriverSide) {
        let mut was_connected = false;
        loop {
            let connected = match socket.take() {
                Some(socket) => socket,
                None => match wait_for_interface(&iface, &mut driver).await {
                    Some(socket) => socket,
                    None => return,
                },
            };
            if was_connected {
                BusCounters::bump(&driver.counters.reconnects);
                tracing::info!(%iface, "CAN interface is back");
            }
            was_connected = true;
            driver.set_status(BusStatus::up());
            match serve(&iface, &connected, &mut driver).await {
                Ended::Closed => return,
                Ended::Lost(reason) => {
                    tracing::warn!(%iface, %reason, "CAN interface lost; retrying every {RECONNECT_INTERVAL:?}");
                    driver.set_status(BusStatus::new(BusState::Down, reason));
                }
            }
        }
    }

    /// Reads and writes until the interface goes away or the bus is dropped.
    async fn serve(iface: &str, socket: &Socket, driver: &mut DriverSide) -> Ended {
        loop {
            tokio::select! {
                read = socket.read() => match read {
                    Ok((raw, timestamps)) => publish(iface, &raw, timestamps, driver),
                    Err(err) if matches!(err.kind(), io::ErrorKind::Interrupted | io::ErrorKind::WouldBlock) => {}
                    // A read of a size that is no CAN frame: odd, not fatal.
                    Err(err) if err.kind() == io::ErrorKind::InvalidData => {
                        BusCounters::bump(&driver.counters.malformed);
                        tracing::debug!(%iface, %err, "unreadable CAN frame skipped");
                    }
                    Err(err) => return Ended::Lost(format!("{iface}: {err}")),
                },
                outgoing = driver.tx.recv() => match outgoing {
                    Some(frame) => match socket.write(&frame).await {
                        Ok(()) => driver.sent(frame),
                        Err(err) => {
                            BusCounters::bump(&driver.counters.tx_errors);
                            tracing::warn!(%iface, %err, %frame, "CAN frame not sent");
                            if interface_gone(&err) {
                                return Ended::Lost(format!("{iface}: {err}"));
                            }
                        }
                    },
                    None => return Ended::Closed,
                },
            }
        }
    }

    fn publish(iface: &str, raw: &CanAnyFrame, timestamps: CanTimestamps, driver: &DriverSide) {
        let frame = match from_socketcan(raw) {
            Ok(frame) => frame,
            Err(err) => {
                BusCounters::bump(&driver.counters.malformed);
                tracing::debug!(%iface, %err, "CAN frame the bus cannot carry skipped");
                return;
            }
        };
        let timestamp = timestamps
            .socket
            .map(Timestamp::from)
            .unwrap_or_else(Timestamp::now);
        driver.received(frame, timestamp);
        let report = error_frame_report(&frame, driver.state());
        if let Some(counters) = report.counters {
            let store = |counter: &std::sync::atomic::AtomicU64, value: u8| {
                counter.store(u64::from(value), std::sync::atomic::Ordering::Relaxed);
            };
            store(&driver.counters.tec, counters.tec);
            store(&driver.counters.rec, counters.rec);
        }
        if let Some(status) = report.status {
            tracing::info!(%iface, state = status.state.as_str(), reason = status.reason.as_deref().unwrap_or(""), "CAN controller state changed");
            driver.set_status(status);
        }
    }

    /// Looks for the interface every [`RECONNECT_INTERVAL`] until it can be
    /// opened and is up; `None` when the bus is dropped meanwhile. Frames
    /// queued for sending meanwhile are dropped and counted: sent late, they
    /// could act on a machine at the wrong moment.
    async fn wait_for_interface(iface: &str, driver: &mut DriverSide) -> Option<Socket> {
        loop {
            let deadline = Instant::now() + RECONNECT_INTERVAL;
            loop {
                tokio::select! {
                    () = tokio::time::sleep_until(deadline) => break,
                    outgoing = driver.tx.recv() => match outgoing {
                        Some(_) => BusCounters::bump(&driver.counters.tx_errors),
                        None => return None,
                    },
                }
            }
            match Socket::open(iface) {
                Ok(socket) if interface_is_up(iface) != Some(false) => return Some(socket),
                Ok(_) => driver.set_status(down_status(iface, "interface is down")),
                Err(err) => driver.set_status(down_status(iface, err)),
            }
        }
    }
}

#[cfg(test)]
mod tests;
