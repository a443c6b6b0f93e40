//! The connection limits against the process's limit of open files
//! (issue 30, finding 6): `--max-connections 5000` under the default 1,024
//! made `accept` fail ("Too many open files") and `/health` and STOP ALL
//! time out. At start the soft limit is raised towards the hard one as far
//! as the listeners need; when that is not enough, the HTTP connection
//! limit is lowered with a warning, and refused when too little is left.

use crate::api::serve::RESERVED_CONNECTIONS;

/// Open files the gateway keeps for itself besides its listeners'
/// connections: the listening sockets, the buses, the database and its
/// journal, the EDS and data files it reads, the log, the runtime's own.
pub(super) const FILES_FOR_THE_GATEWAY: u64 = 64;

/// What the limit of open files leaves to the HTTP connections.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) enum Fit {
    /// Room for all of them.
    Fits,
    /// Only this many, with the warning to log.
    Lowered(usize, String),
}

/// How many of `http` HTTP connections fit under `limit` open files, with
/// `others` taken by the other listeners (CiA 309-3, socketcand shares)
/// and [`FILES_FOR_THE_GATEWAY`] kept; an error when fewer than the
/// reserve for `/health` and STOP ALL and one more would.
pub(super) fn fit(limit: u64, http: usize, others: usize) -> Result<Fit, String> {
    let needed = http as u64 + others as u64 + FILES_FOR_THE_GATEWAY;
    if needed <= limit {
        return Ok(Fit::Fits);
    }
    let room = limit.saturating_sub(others as u64 + FILES_FOR_THE_GATEWAY);
    let least = RESERVED_CONNECTIONS as u64 + 1;
    if room < least {
        return Err(format!(
            "max_connections {http}: the process may open {limit} files; with {others} for the other listeners \
             (ascii_max_connections, share_max_connections) and {FILES_FOR_THE_GATEWAY} for the gateway itself, \
             fewer than {least} are left for HTTP connections: raise the limit of open files (ulimit -n, LimitNOFILE=) \
             or lower the connection limits"
        ));
    }
    Ok(Fit::Lowered(
        room as usize,
        format!(
            "max_connections {http} lowered to {room}: the process may open {limit} files, {others} of them \
             for the other listeners and {FILES_FOR_THE_GATEWAY} kept for the gateway itself (raise the limit \
             of open files: ulimit -n, LimitNOFILE=)"
        ),
    ))
}

/// The process's soft limit of open files, first raised towards its hard
/// limit as far as `wanted` (raising it needs no privilege); `None` where
/// it cannot be read.
#[cfg(unix)]
#[allow(unsafe_code)] // two calls into the C library, on a local struct
#[allow(clippy::unnecessary_cast)] // rlim_t is u64 here, not on every Unix
pub(super) fn raised_limit(wanted: u64) -> Option<u64> {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit and setrlimit only read and write the struct given.
    if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } != 0 {
        return None;
    }
    let current = limit.rlim_cur as u64;
    if current >= wanted || limit.rlim_cur == libc::RLIM_INFINITY {
        return Some(current.max(wanted));
    }
    let raised = libc::rlimit {
        rlim_cur: if limit.rlim_max == libc::RLIM_INFINITY {
            wanted as libc::rlim_t
        } else {
            (wanted as libc::rlim_t).min(limit.rlim_max)
        },
        rlim_max: limit.rlim_max,
    };
    // SAFETY: as above.
    if unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &raised) } == 0 {
        Some(raised.rlim_cur as u64)
    } else {
        Some(current)
    }
}

#[cfg(not(unix))]
pub(super) fn raised_limit(_wanted: u64) -> Option<u64> {
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn connections_are_lowered_to_what_the_limit_leaves_or_refused() {
        assert_eq!(fit(1024, 512, 32), Ok(Fit::Fits));
        assert_eq!(fit(1024, 1024 - 32 - 64, 32), Ok(Fit::Fits));
        let Ok(Fit::Lowered(room, warning)) = fit(1024, 5000, 32) else {
            panic!("{:?}", fit(1024, 5000, 32));
        };
        assert_eq!(room, 1024 - 32 - 64);
        assert!(
            warning.contains("max_connections 5000 lowered to 928"),
            "{warning}"
        );
        // Room for the reserve and one more: lowered; less: refused.
        assert!(matches!(fit(64 + 17, 5000, 0), Ok(Fit::Lowered(17, _))));
        let err = fit(64 + 16, 5000, 0).unwrap_err();
        assert!(err.contains("fewer than 17"), "{err}");
        assert!(fit(10, 512, 0).is_err());
    }
}
