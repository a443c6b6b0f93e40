//! `candeck dump`: a bus printed as a candump `-L` log on stdout.

use std::time::Duration;

use clap::Args;

use super::{CliError, open_bus, shutdown_signal};
use crate::can::candump::record_bus;
use crate::can::spec::BusSpec;
use crate::can::{Bus, BusKind, BusState};

#[derive(Debug, Args)]
pub struct DumpArgs {
    /// The bus: virtual:empty, socketcand:HOST:PORT/CHANNEL, socketcan:IFACE, replay:FILE.
    #[arg(long, value_name = "SPEC")]
    pub bus: BusSpec,
    /// Stop after this many frames.
    #[arg(long, value_name = "N")]
    pub count: Option<u64>,
    /// Stop after this many seconds.
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
    /// How long to wait for the bus to come up before giving up, in seconds.
    #[arg(long, value_name = "S", default_value_t = 5.0)]
    pub connect_timeout: f64,
}

fn seconds(value: f64, option: &str) -> Result<Duration, CliError> {
    Duration::try_from_secs_f64(value).map_err(|_| {
        CliError::new(format!(
            "{option} {value}: expected a number of seconds, 0 or more"
        ))
    })
}

pub async fn run(args: DumpArgs) -> Result<(), CliError> {
    let connect_timeout = seconds(args.connect_timeout, "--connect-timeout")?;
    let stop_after = args.seconds.map(|s| seconds(s, "--seconds")).transpose()?;
    // The demo devices of virtual:demo run as long as the dump does.
    let name = args.bus.default_name();
    let opened = open_bus(&args.bus).await?;
    let bus = opened.bus.clone();
    bus.wait_up(connect_timeout).await.map_err(CliError::new)?;
    tracing::info!("dump: {} is up; writing candump -L to stdout", bus.spec());

    // A remote bus that drops is waited for (it reconnects); a replay that
    // is over ends the dump.
    let status_log = tokio::spawn(log_status_changes(bus.clone()));
    let mut status = bus.watch_status();
    let replay = bus.kind() == BusKind::Replay;
    let stop = async move {
        let replay_over = async {
            if replay {
                let _ = status.wait_for(|s| s.state == BusState::Down).await;
            } else {
                std::future::pending::<()>().await;
            }
        };
        tokio::select! {
            _ = shutdown_signal() => {}
            _ = sleep_for(stop_after) => {}
            _ = replay_over => {}
        }
    };
    let result = record_bus(&bus, &name, tokio::io::stdout(), args.count, stop).await;
    status_log.abort();
    match result {
        Ok(summary) => {
            tracing::info!(
                "dump: {} frames written, {} lost",
                summary.written,
                summary.lost
            );
            Ok(())
        }
        // A closed pipe (`candeck dump | head`) ends the dump quietly.
        Err(err) if err.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        Err(err) => Err(CliError::new(format!("cannot write to stdout: {err}"))),
    }
}

async fn log_status_changes(bus: Bus) {
    let mut status = bus.watch_status();
    // The state the dump started in is already logged; only changes follow.
    status.borrow_and_update();
    while status.changed().await.is_ok() {
        let now = status.borrow_and_update().clone();
        let reason = now.reason.map(|r| format!(": {r}")).unwrap_or_default();
        // A replay that has played its log is down as planned.
        if now.state.can_send() || bus.kind() == BusKind::Replay {
            tracing::info!("dump: bus {} is {}{reason}", bus.name(), now.state.as_str());
        } else {
            tracing::warn!("dump: bus {} is {}{reason}", bus.name(), now.state.as_str());
        }
    }
}

async fn sleep_for(duration: Option<Duration>) {
    match duration {
        Some(duration) => tokio::time::sleep(duration).await,
        None => std::future::pending().await,
    }
}
