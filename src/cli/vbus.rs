//! `candeck vbus`: an emulated bus shared over socketcand.

use std::net::SocketAddr;

use clap::Args;

use super::{CliError, shutdown_signal};
use crate::can::socketcand::DEFAULT_PORT;
use crate::can::socketcand::{ServerConfig, SocketcandServer};
use crate::can::{Bitrate, VirtualHub};
use crate::sim::products::DeviceList;
use crate::sim::rack::Rack;

fn default_vbus_listen() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], DEFAULT_PORT))
}

#[derive(Debug, Args)]
pub struct VbusArgs {
    /// Address the socketcand server listens on (port 0 picks a free port).
    #[arg(long, default_value_t = default_vbus_listen())]
    pub listen: SocketAddr,
    /// Virtual devices on the bus: `demo` (UMC1BDS32 at 1, JMC at 2, UIO1LED
    /// at 3), `none`, or a list like `umc1bds32@1,jmc@2,uio1led@3` (products:
    /// umc1bds32, umc1bd90, jmc, uio1led, io401); `uio1led@lss` or
    /// `uio1led@lss/SERIAL` is a device without a node-ID, waiting for an
    /// LSS master (CiA 305).
    #[arg(long, default_value = "demo")]
    pub devices: DeviceList,
    /// The socketcand channel name clients open.
    #[arg(long, default_value = "can0")]
    pub channel: String,
    /// Where the devices keep what they save (0x1010) across restarts;
    /// without it, saved values last until candeck stops.
    #[arg(long, value_name = "DIR")]
    pub data_dir: Option<std::path::PathBuf>,
    /// The bus's bit rate in bit/s (`125000`, `250k`, `1M`): each frame takes
    /// its time on the wire and the lowest identifier wins arbitration;
    /// `unlimited` lets every frame cross at once (for benchmarks of the
    /// software).
    #[arg(long, value_name = "N|unlimited", default_value_t = Bitrate::default())]
    pub bitrate: Bitrate,
}

pub async fn run(args: VbusArgs) -> Result<(), CliError> {
    if args.channel.is_empty()
        || args.channel.len() > 16
        || args.channel.contains(char::is_whitespace)
    {
        return Err(CliError::new(format!(
            "--channel '{}': a channel name has 1 to 16 characters and no spaces",
            args.channel
        )));
    }
    let hub = VirtualHub::with_bitrate(args.channel.clone(), args.bitrate);
    let rack = Rack::with_data_dir(hub.clone(), args.data_dir.clone());
    rack.add_all(&args.devices.0)
        .map_err(|err| CliError::new(err.to_string()))?;
    let server = SocketcandServer::bind(
        args.listen,
        [(args.channel.clone(), hub.clone())],
        ServerConfig::default(),
    )
    .await
    .map_err(|err| CliError::new(format!("cannot listen on {}: {err}", args.listen)))?;
    let handle = server
        .spawn()
        .map_err(|err| CliError::new(format!("cannot listen on {}: {err}", args.listen)))?;
    // One line on stdout that people and scripts read (the port, when 0 was asked).
    crate::cli::say(format_args!(
        "candeck vbus: socketcand on {} channel {} devices {} bitrate {}",
        handle.local_addr(),
        args.channel,
        args.devices,
        args.bitrate
    ));
    shutdown_signal().await;
    let stats = rack.stats();
    tracing::info!(
        "vbus: stopping after {} frames, {} clients served; simulation: {} ticks, {} more than {} ms late, latest {} µs late, {} simulated ms skipped, longest wake-up {} µs",
        hub.frames_total(),
        handle
            .stats()
            .accepted
            .load(std::sync::atomic::Ordering::Relaxed),
        stats.ticks.load(std::sync::atomic::Ordering::Relaxed),
        stats.late_ticks.load(std::sync::atomic::Ordering::Relaxed),
        crate::sim::rack::ON_TIME.as_millis(),
        stats
            .max_lateness_us
            .load(std::sync::atomic::Ordering::Relaxed),
        rack.skipped_ticks(),
        stats.max_busy_us.load(std::sync::atomic::Ordering::Relaxed),
    );
    Ok(())
}
