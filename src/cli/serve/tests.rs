use std::path::{Path, PathBuf};

use clap::Parser;

use super::args::*;
use crate::cli::{Cli, Command};
use crate::gateway::DEFAULT_AXIS_POLL_HZ;
use crate::gateway::Retention;
use crate::gateway::Role;

fn serve_args(args: &[&str]) -> Result<ServeArgs, String> {
    let cli = Cli::try_parse_from(["candeck", "serve"].iter().chain(args))
        .map_err(|err| err.to_string())?;
    match cli.command {
        Some(Command::Serve(args)) => Ok(args),
        other => Err(format!("not serve: {other:?}")),
    }
}

/// The config key of a `candeck serve` option: its long name with
/// underscores; the repeated options' keys are plural.
fn config_key(long: &str) -> String {
    match long {
        "bus" => "buses".to_string(),
        "cors-origin" => "cors_origins".to_string(),
        "allowed-host" => "allowed_hosts".to_string(),
        long => long.replace('-', "_"),
    }
}

#[test]
fn the_example_config_parses_and_has_a_key_for_every_option() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("candeck.example.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    // "#= " lines are settings left out on purpose: with them too.
    let full: String = text
        .lines()
        .map(|line| line.strip_prefix("#= ").unwrap_or(line))
        .collect::<Vec<_>>()
        .join("\n");
    let dir = std::env::temp_dir().join(format!("candeck-example-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let full_path = dir.join("full.toml");
    std::fs::write(&full_path, &full).unwrap();
    // The DCF of the example's [[nodes]], next to it.
    std::fs::write(
        dir.join("lift.dcf"),
        "[DeviceComissioning]\nNodeID=1\n\n[2000]\nParameterName=Some parameter\nObjectType=0x7\nDataType=0x0005\nAccessType=rw\nDefaultValue=0\nParameterValue=7\n",
    )
    .unwrap();

    // As shipped (tokens from the environment, as the systemd unit
    // gives them) and with every setting.
    let shipped = serve_args(&["--config", path.to_str().unwrap()])
        .unwrap()
        .settings_with(Some("hmi:viewer:3f9c2a7be81d4c06a5e9"))
        .unwrap();
    assert_eq!(shipped.buses.len(), 2);
    assert_eq!(shipped.data_dir, Some(PathBuf::from("/var/lib/candeck")));
    let settings = serve_args(&["--config", full_path.to_str().unwrap()])
        .unwrap()
        .settings_with(None)
        .unwrap();
    assert_eq!(settings.auth.tokens[0].name, "line-plc");
    let lift = &settings.machine_nodes["line"][0];
    assert_eq!((lift.id.get(), lift.heartbeat_ms), (1, 200));
    assert_eq!(lift.config.len(), 1);
    assert_eq!(lift.identity.revision_max, Some(0x0100_FFFF));
    assert_eq!(settings.machine.manager.heartbeat_ms, 100);
    assert_eq!(
        shipped.sdo_samples_per_s,
        crate::gateway::DEFAULT_SDO_SAMPLES_PER_S
    );
    assert_eq!(settings.gateway_config().sdo_samples_per_s, 20);
    assert_eq!(settings.machine.manager.consumer_factor.get(), 3.0);
    assert_eq!(
        settings.ascii_listen,
        Some("127.0.0.1:60000".parse().unwrap())
    );
    // The OPC UA server is off as shipped, and every key of it parses.
    assert_eq!(shipped.opcua, None);
    let opcua = settings.opcua.as_ref().unwrap();
    assert_eq!(opcua.listen, "127.0.0.1:4840".parse().unwrap());
    assert_eq!(opcua.pki_dir, PathBuf::from("/var/lib/candeck/opcua-pki"));
    assert_eq!(opcua.limits.max_sessions, 20);
    // The edge node is off as shipped, and every key of it parses.
    assert_eq!(shipped.sparkplug, None);
    let sparkplug = settings.sparkplug.unwrap();
    assert_eq!(sparkplug.role, Role::Operator);
    assert_eq!(sparkplug.policy.rules.len(), 1);

    // Every option of `candeck serve` but --config itself has a key in
    // the example: a new flag without one fails here.
    let keys: toml::Table = toml::from_str(&full).unwrap();
    let command = <Cli as clap::CommandFactory>::command();
    let serve = command.find_subcommand("serve").unwrap();
    let mut missing = Vec::new();
    for arg in serve.get_arguments() {
        let Some(long) = arg.get_long() else { continue };
        if ["config", "log", "help", "version"].contains(&long) {
            continue;
        }
        let key = config_key(long);
        if !keys.contains_key(&key) {
            missing.push(key);
        }
    }
    assert!(
        missing.is_empty(),
        "no key in candeck.example.toml: {missing:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn insecure_opens_the_opcua_server_beyond_loopback_as_it_opens_rest() {
    // The demo container: every address inside, published on the host's
    // loopback, no tokens.
    let settings = serve_args(&["--opcua-listen", "0.0.0.0:4840", "--insecure"])
        .unwrap()
        .settings_with(None)
        .unwrap();
    let opcua = settings.opcua.as_ref().unwrap();
    assert!(opcua.logins.anonymous && !opcua.logins.users);
    // Anonymous there only over signed, encrypted channels.
    assert!(!opcua.logins.unsecured_endpoint);
    let warnings = settings.listeners().unwrap();
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("OPC UA server on 0.0.0.0:4840")),
        "{warnings:?}"
    );
}

#[test]
fn the_opcua_server_follows_rests_rule_for_who_may_reach_it() {
    let open = serve_args(&["--opcua-listen", "127.0.0.1:0"])
        .unwrap()
        .settings_with(None)
        .unwrap()
        .opcua
        .unwrap();
    assert!(open.logins.anonymous && open.logins.unsecured_endpoint);
    assert_eq!(open.pki_dir, PathBuf::from("opcua-pki"));
    let err = serve_args(&["--opcua-listen", "0.0.0.0:4840"])
        .unwrap()
        .settings_with(None)
        .unwrap_err();
    assert!(err.contains("opcua_listen"), "{err}");
    let with_tokens = serve_args(&[
        "--opcua-listen",
        "0.0.0.0:4840",
        "--data-dir",
        "/srv/candeck",
    ])
    .unwrap()
    .settings_with(Some("plc:operator:3f9c2a7be81d4c06a5e9"))
    .unwrap()
    .opcua
    .unwrap();
    assert!(with_tokens.logins.users && !with_tokens.logins.anonymous);
    assert!(!with_tokens.logins.unsecured_endpoint);
    assert_eq!(with_tokens.pki_dir, PathBuf::from("/srv/candeck/opcua-pki"));
    assert_eq!(
        serve_args(&[]).unwrap().settings_with(None).unwrap().opcua,
        None
    );
}

#[test]
fn every_option_of_every_command_has_its_help() {
    fn check(command: &clap::Command, path: &str, missing: &mut Vec<String>) {
        if command.get_about().is_none() && !path.is_empty() {
            missing.push(format!("{path} (the command)"));
        }
        for arg in command.get_arguments() {
            let id = arg.get_id().as_str();
            if !["help", "version"].contains(&id) && arg.get_help().is_none() {
                missing.push(format!("{path} {id}"));
            }
        }
        for sub in command.get_subcommands() {
            check(sub, &format!("{path} {}", sub.get_name()), missing);
        }
    }
    let mut missing = Vec::new();
    check(&<Cli as clap::CommandFactory>::command(), "", &mut missing);
    assert!(missing.is_empty(), "without help: {missing:?}");
}

#[test]
fn the_sync_period_and_insecure_come_from_the_file_and_the_command_line() {
    let dir = std::env::temp_dir().join(format!("candeck-sync-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("sync.toml");
    std::fs::write(
        &file,
        "listen = \"0.0.0.0:8080\"\ninsecure = true\nsync_period_ms = 10\n",
    )
    .unwrap();
    let file = file.to_str().unwrap();

    let settings = serve_args(&[]).unwrap().settings_with(None).unwrap();
    assert_eq!(settings.sync_period, std::time::Duration::ZERO);
    let settings = serve_args(&["--config", file])
        .unwrap()
        .settings_with(None)
        .unwrap();
    assert_eq!(settings.sync_period, std::time::Duration::from_millis(10));
    assert!(settings.insecure);
    let settings = serve_args(&["--config", file, "--sync-period-ms", "0"])
        .unwrap()
        .settings_with(None)
        .unwrap();
    assert_eq!(settings.sync_period, std::time::Duration::ZERO);

    let err = serve_args(&["--sync-period-ms", "5000000"]).unwrap_err();
    assert!(err.contains("a SYNC period is at most"), "{err}");
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "sync_period_ms = 4294968\n").unwrap();
    let err = serve_args(&["--config", bad.to_str().unwrap()])
        .unwrap()
        .settings_with(None)
        .unwrap_err();
    assert!(err.contains("sync_period_ms"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_sdo_sampling_bound_is_read_under_its_name_and_its_first_one_and_checked() {
    let dir = std::env::temp_dir().join(format!("candeck-samples-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let settings_of = |text: &str| {
        let file = dir.join("samples.toml");
        std::fs::write(&file, text).unwrap();
        serve_args(&["--config", file.to_str().unwrap()])
            .unwrap()
            .settings_with(None)
    };
    let bound = |text: &str| {
        settings_of(text)
            .unwrap()
            .gateway_config()
            .sdo_samples_per_s
    };
    assert_eq!(bound("sdo_samples_per_s = 7\n"), 7);
    assert_eq!(bound("opcua_sdo_samples_per_s = 9\n"), 9);
    assert_eq!(bound(""), crate::gateway::DEFAULT_SDO_SAMPLES_PER_S);
    for bad in [
        "sdo_samples_per_s = 0\n",
        "opcua_sdo_samples_per_s = 5000\n",
    ] {
        let err = settings_of(bad).unwrap_err();
        assert!(
            err.contains("sdo_samples_per_s") && err.contains("between 1 and 1000"),
            "{err}"
        );
    }
    // Both names at once: which one counts would be a guess.
    let err = settings_of("sdo_samples_per_s = 7\nopcua_sdo_samples_per_s = 9\n").unwrap_err();
    assert!(err.contains("sdo_samples_per_s"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_ascii_listener_comes_from_the_command_line_over_the_file() {
    let dir = std::env::temp_dir().join(format!("candeck-ascii-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("ascii.toml");
    std::fs::write(&file, "ascii_listen = \"127.0.0.1:6000\"\n").unwrap();
    let file = file.to_str().unwrap();

    assert_eq!(
        serve_args(&[]).unwrap().settings().unwrap().ascii_listen,
        None
    );
    let settings = serve_args(&["--config", file]).unwrap().settings().unwrap();
    assert_eq!(
        settings.ascii_listen,
        Some("127.0.0.1:6000".parse().unwrap())
    );
    let settings = serve_args(&["--config", file, "--ascii-listen", "127.0.0.2:6001"])
        .unwrap()
        .settings()
        .unwrap();
    assert_eq!(
        settings.ascii_listen,
        Some("127.0.0.2:6001".parse().unwrap())
    );
    assert!(serve_args(&["--ascii-listen", "nowhere"]).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn retention_comes_from_the_command_line_over_the_file_over_the_default() {
    let dir = std::env::temp_dir().join(format!("candeck-retention-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("retention.toml");
    std::fs::write(&file, "retention_days = 7\nretention_rows = 500\n").unwrap();
    let file = file.to_str().unwrap();

    let settings = serve_args(&[]).unwrap().settings().unwrap();
    assert_eq!(settings.retention, Retention::default());
    let settings = serve_args(&["--config", file]).unwrap().settings().unwrap();
    assert_eq!(
        settings.retention,
        Retention {
            days: Some(7),
            rows: Some(500)
        }
    );
    // 0 lifts a limit.
    let settings = serve_args(&["--config", file, "--retention-days", "0"])
        .unwrap()
        .settings()
        .unwrap();
    assert_eq!(
        settings.retention,
        Retention {
            days: None,
            rows: Some(500)
        }
    );
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "retention_rows = -1\n").unwrap();
    let err = serve_args(&["--config", bad.to_str().unwrap()])
        .unwrap()
        .settings()
        .unwrap_err();
    assert!(err.contains("line 1"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_axis_poll_rate_comes_from_the_command_line_over_the_file_over_the_default() {
    let dir = std::env::temp_dir().join(format!("candeck-serve-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("poll.toml");
    std::fs::write(&file, "axis_poll_hz = 50\n").unwrap();
    let file = file.to_str().unwrap();

    let settings = serve_args(&[]).unwrap().settings().unwrap();
    assert_eq!(settings.axis_poll_hz, DEFAULT_AXIS_POLL_HZ);
    let settings = serve_args(&["--config", file]).unwrap().settings().unwrap();
    assert_eq!(settings.axis_poll_hz, 50.0);
    let settings = serve_args(&["--config", file, "--axis-poll-hz", "12.5"])
        .unwrap()
        .settings()
        .unwrap();
    assert_eq!(settings.axis_poll_hz, 12.5);

    for bad in ["0", "-3", "nan", "fast", "150"] {
        let err = serve_args(&[&format!("--axis-poll-hz={bad}")]).unwrap_err();
        assert!(err.contains("--axis-poll-hz"), "{bad}: {err}");
    }
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "axis_poll_hz = 0\n").unwrap();
    let err = serve_args(&["--config", bad.to_str().unwrap()])
        .unwrap()
        .settings()
        .unwrap_err();
    assert!(err.contains("axis_poll_hz"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn without_tokens_only_loopback_is_served_unless_insecure() {
    let settings = serve_args(&[]).unwrap().settings_with(None).unwrap();
    assert!(settings.exposure().unwrap().unwrap().contains("no tokens"));
    let err = serve_args(&["--listen", "0.0.0.0:8080"])
        .unwrap()
        .settings_with(None)
        .unwrap_err();
    assert!(
        err.contains("refusing to listen on 0.0.0.0:8080 without tokens"),
        "{err}"
    );
    let settings = serve_args(&["--listen", "0.0.0.0:8080", "--insecure"])
        .unwrap()
        .settings_with(None)
        .unwrap();
    assert!(settings.exposure().unwrap().unwrap().contains("--insecure"));
    let settings = serve_args(&["--listen", "[::]:8080"])
        .unwrap()
        .settings_with(Some("plc:operator:3f9c2a7be81d4c06a5e9"))
        .unwrap();
    assert_eq!(settings.exposure(), Ok(None));
    assert_eq!(settings.auth.tokens[0].name, "plc");
}

#[test]
fn tokens_and_limits_come_from_the_file_and_the_environment() {
    let dir = std::env::temp_dir().join(format!("candeck-auth-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("auth.toml");
    std::fs::write(
        &file,
        "cors_origins = [\"https://scada.example\"]\nwrite_rate = 5\nbody_limit = 2048\n\
         [[tokens]]\nname = \"line-plc\"\nrole = \"operator\"\ntoken = \"3f9c2a7be81d4c06a5e9\"\n",
    )
    .unwrap();
    let path = file.to_str().unwrap();
    let settings = serve_args(&["--config", path])
        .unwrap()
        .settings_with(Some("hmi:viewer:0123456789abcdefghij"))
        .unwrap();
    let names: Vec<(&str, Role)> = settings
        .auth
        .tokens
        .iter()
        .map(|t| (t.name.as_str(), t.role))
        .collect();
    assert_eq!(names, [("line-plc", Role::Operator), ("hmi", Role::Viewer)]);
    assert_eq!(settings.auth.cors_origins, ["https://scada.example"]);
    assert_eq!(settings.auth.rate_limit.unwrap().per_second, 5.0);
    assert_eq!(settings.auth.body_limit, 2048);
    // The command line wins; 0 turns the rate limit off.
    let settings = serve_args(&["--config", path, "--write-rate", "0"])
        .unwrap()
        .settings_with(None)
        .unwrap();
    assert_eq!(settings.auth.rate_limit, None);
    // The same token twice, a weak one, an unknown role: refused.
    let err = serve_args(&["--config", path])
        .unwrap()
        .settings_with(Some("other:admin:3f9c2a7be81d4c06a5e9"))
        .unwrap_err();
    assert!(err.contains("the same token"), "{err}");
    let err = serve_args(&[])
        .unwrap()
        .settings_with(Some("plc:operator:secret"))
        .unwrap_err();
    assert!(
        err.starts_with("CANDECK_TOKENS: token plc:") && err.contains("too weak"),
        "{err}"
    );
    // Fields swapped: the error says what is wrong, never the secret
    // (issue 19, point 10).
    let secret = "3f9c2a7be81d4c06a5e9";
    for entry in [
        format!("plc:{secret}:operator"),
        format!("{secret}:operator:plc"),
        format!("{secret}:plc:operator"),
    ] {
        let err = serve_args(&[])
            .unwrap()
            .settings_with(Some(&entry))
            .unwrap_err();
        assert!(err.starts_with("CANDECK_TOKENS: token "), "{err}");
        assert!(!err.contains(secret), "{entry}: {err}");
    }
    let err = serve_args(&[])
        .unwrap()
        .settings_with(Some(&format!("plc:{secret}:operator")))
        .unwrap_err();
    assert!(err.contains("not a role"), "{err}");
    std::fs::write(
        &file,
        "[[tokens]]\nname = \"x\"\nrole = \"root\"\ntoken = \"3f9c2a7be81d4c06a5e9\"\n",
    )
    .unwrap();
    let err = serve_args(&["--config", path])
        .unwrap()
        .settings_with(None)
        .unwrap_err();
    assert!(err.contains("unknown role 'root'"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_recordings_quota_comes_from_the_command_line_over_the_file_over_the_default() {
    let dir = std::env::temp_dir().join(format!("candeck-quota-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("quota.toml");
    std::fs::write(&file, "recordings_quota_mb = 20\n").unwrap();
    let file = file.to_str().unwrap();
    let quota = |args: &[&str]| {
        serve_args(args)
            .unwrap()
            .settings_with(None)
            .unwrap()
            .recordings_quota
    };
    assert_eq!(quota(&[]), Some(1024 * 1024 * 1024));
    assert_eq!(quota(&["--config", file]), Some(20 * 1024 * 1024));
    assert_eq!(
        quota(&["--config", file, "--recordings-quota-mb", "5"]),
        Some(5 * 1024 * 1024)
    );
    assert_eq!(quota(&["--recordings-quota-mb", "0"]), None);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn every_listener_follows_the_loopback_rule_and_the_share_needs_its_own_flag() {
    const TOKENS: Option<&str> = Some("plc:operator:3f9c2a7be81d4c06a5e9");
    // CiA 309-3 moves motors as the API does: the same rule.
    let err = serve_args(&["--ascii-listen", "0.0.0.0:5000"])
        .unwrap()
        .settings_with(None)
        .unwrap_err();
    assert!(
        err.contains("refusing --ascii-listen 0.0.0.0:5000 without tokens"),
        "{err}"
    );
    for (args, tokens) in [
        (&["--ascii-listen", "0.0.0.0:5000"][..], TOKENS),
        (&["--ascii-listen", "127.0.0.1:5000"][..], None),
    ] {
        let settings = serve_args(args).unwrap().settings_with(tokens).unwrap();
        assert!(settings.listeners().unwrap().is_empty(), "{args:?}");
    }
    let settings = serve_args(&["--ascii-listen", "0.0.0.0:5000", "--insecure"])
        .unwrap()
        .settings_with(None)
        .unwrap();
    let warnings = settings.listeners().unwrap();
    assert!(
        warnings[0].contains("CiA 309-3 port on 0.0.0.0:5000"),
        "{warnings:?}"
    );

    // A share is raw bus access that no token guards: tokens do not open it.
    for tokens in [None, TOKENS] {
        let err = serve_args(&["--share", "0.0.0.0:29536"])
            .unwrap()
            .settings_with(tokens)
            .unwrap_err();
        assert!(err.contains("refusing --share 0.0.0.0:29536"), "{err}");
        assert!(err.contains("--share-public"), "{err}");
    }
    let settings = serve_args(&["--share", "0.0.0.0:29536", "--share-public"])
        .unwrap()
        .settings_with(TOKENS)
        .unwrap();
    let warnings = settings.listeners().unwrap();
    assert!(warnings[0].contains("raw bus access"), "{warnings:?}");
    let settings = serve_args(&["--share", "127.0.0.1:29536"])
        .unwrap()
        .settings_with(TOKENS)
        .unwrap();
    assert!(settings.listeners().unwrap().is_empty());

    // Beyond loopback the gateway cannot know its names: the warning says
    // to list them.
    let settings = serve_args(&["--listen", "0.0.0.0:8080"])
        .unwrap()
        .settings_with(TOKENS)
        .unwrap();
    let warnings = settings.listeners().unwrap();
    assert!(warnings[0].contains("allowed_hosts"), "{warnings:?}");
    let settings = serve_args(&["--listen", "0.0.0.0:8080", "--allowed-host", "gw.example"])
        .unwrap()
        .settings_with(TOKENS)
        .unwrap();
    assert!(settings.listeners().unwrap().is_empty());
}

#[test]
fn the_connection_limits_come_from_the_command_line_over_the_file_over_the_default() {
    use std::time::Duration;
    let settings = serve_args(&[]).unwrap().settings_with(None).unwrap();
    assert_eq!(settings.http_limits, crate::api::serve::Limits::default());
    assert_eq!(settings.ascii_limits, crate::ascii::Limits::default());
    let dir = std::env::temp_dir().join(format!("candeck-limits-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("limits.toml");
    std::fs::write(
        &file,
        "header_timeout_ms = 2000\nidle_timeout_ms = 3000\nmax_connections = 100\nascii_idle_timeout_ms = 4000\nascii_max_connections = 5\nascii_unauthenticated_timeout_ms = 6000\nshare_max_connections = 7\nallowed_hosts = [\"gw.example\"]\n",
    )
    .unwrap();
    let file = file.to_str().unwrap();
    let settings = serve_args(&["--config", file, "--max-connections", "50"])
        .unwrap()
        .settings_with(None)
        .unwrap();
    assert_eq!(settings.http_limits.header_timeout, Duration::from_secs(2));
    assert_eq!(settings.http_limits.idle_timeout, Duration::from_secs(3));
    assert_eq!(settings.http_limits.max_connections, 50);
    assert_eq!(settings.ascii_limits.idle_timeout, Duration::from_secs(4));
    assert_eq!(settings.ascii_limits.max_connections, 5);
    assert_eq!(
        settings.ascii_limits.unauthenticated_timeout,
        Duration::from_secs(6)
    );
    assert_eq!(settings.share_max_connections, 7);
    assert!(settings.allowed_hosts.allows("gw.example:8080"));
    for (args, expected) in [
        (&["--max-connections", "16"][..], "max_connections 16"),
        (&["--header-timeout-ms", "0"][..], "at least 1 ms"),
        (
            &["--ascii-max-connections", "0"][..],
            "ascii_max_connections",
        ),
        (&["--allowed-host", "http://gw"][..], "no host name"),
        (
            &["--share-max-connections", "0"][..],
            "share_max_connections",
        ),
    ] {
        let err = serve_args(args).unwrap().settings_with(None).unwrap_err();
        assert!(err.contains(expected), "{args:?}: {err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_sparkplug_edge_node_comes_from_the_config_file_and_is_off_without_mqtt_url() {
    let dir = std::env::temp_dir().join(format!("candeck-sparkplug-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("candeck.toml");
    let settings = |text: &str| {
        std::fs::write(&file, text).unwrap();
        serve_args(&["--config", file.to_str().unwrap()])
            .unwrap()
            .settings_with(None)
    };
    assert_eq!(settings("").unwrap().sparkplug, None);
    let config = settings(
        "mqtt_url = \"mqtt://127.0.0.1:1884\"\nsparkplug_group_id = \"plant\"\n\
         sparkplug_edge_node_id = \"line1\"\nsparkplug_max_rate_hz = 10\n\
         [[sparkplug_metrics]]\nmetric = \"Position\"\ndeadband = 5\n",
    )
    .unwrap()
    .sparkplug
    .unwrap();
    assert_eq!(config.broker.port, 1884);
    assert_eq!(
        (config.group_id.as_str(), config.edge_node_id.as_str()),
        ("plant", "line1")
    );
    // Commands from MQTT are refused unless a role is given.
    assert_eq!(config.role, Role::Viewer);
    assert_eq!(config.policy.default.min_interval_ms, 100);
    assert_eq!(config.policy.reporting("TPDO/Position").deadband, 5.0);
    assert_eq!(config.spool_file, None);
    assert_eq!(config.publish_tick, std::time::Duration::from_millis(10));
    let tick = |ms: &str| {
        settings(&format!(
            "mqtt_url = \"mqtt://b\"\nsparkplug_group_id = \"g\"\nsparkplug_publish_tick_ms = {ms}\n"
        ))
    };
    assert_eq!(
        tick("0").unwrap().sparkplug.unwrap().publish_tick,
        std::time::Duration::ZERO
    );
    let err = tick("1001").unwrap_err();
    assert!(err.contains("sparkplug_publish_tick_ms"), "{err}");
    let err = settings("mqtt_url = \"mqtt://b\"\n").unwrap_err();
    assert!(err.contains("sparkplug_group_id"), "{err}");
    let err = settings("mqtt_url = \"mqtts://b\"\nsparkplug_group_id = \"g\"\n").unwrap_err();
    assert!(err.contains("mqtt_ca_file"), "{err}");
    let err = settings("mqtt_url = \"mqtt://b\"\nsparkplug_group_id = \"a/b\"\n").unwrap_err();
    assert!(err.contains("sparkplug_group_id"), "{err}");
    let err = settings(
        "mqtt_url = \"mqtt://b\"\nsparkplug_group_id = \"g\"\nsparkplug_role = \"boss\"\n",
    )
    .unwrap_err();
    assert!(err.contains("sparkplug_role"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_compose_sparkplug_demo_configs_parse_as_two_edge_nodes_of_one_group() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/sparkplug");
    let mut edge_nodes = Vec::new();
    for line in ["a", "b"] {
        let path = dir.join(format!("line-{line}.toml"));
        let settings = serve_args(&["--config", path.to_str().unwrap()])
            .unwrap()
            .settings_with(None)
            .unwrap();
        let sparkplug = settings.sparkplug.unwrap();
        assert_eq!(sparkplug.group_id, "plant");
        assert_eq!(sparkplug.broker.host, "mosquitto");
        edge_nodes.push(sparkplug.edge_node_id);
    }
    assert_eq!(edge_nodes, ["line-a", "line-b"]);
}

/// Issue 30, finding 8: the values of a `[[nodes]]` entry are checked for
/// their range and consistency at start, the error naming the accepted
/// range.
#[test]
fn node_entries_with_values_out_of_range_or_inconsistent_are_refused() {
    let dir = std::env::temp_dir().join(format!("candeck-node-ranges-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("nodes.toml");
    for (entry, expected) in [
        (
            "heartbeat_ms = 1",
            "heartbeat_ms 1: give 0 (not supervised) or 50 to 65535 ms",
        ),
        (
            "revision_min = 0x0200\nrevision_max = 0x0100",
            "revision_min 0x00000200 is above revision_max 0x00000100",
        ),
        ("name = \" \"", "name: empty"),
    ] {
        std::fs::write(&file, format!("[[nodes]]\nid = 5\n{entry}\n")).unwrap();
        let err = serve_args(&["--config", file.to_str().unwrap()])
            .unwrap()
            .settings_with(None)
            .unwrap_err();
        assert!(err.contains("config [[nodes]] id 5"), "{entry}: {err}");
        assert!(err.contains(expected), "{entry}: {err}");
    }
    // The edges of the ranges stand.
    std::fs::write(
        &file,
        "[[nodes]]\nid = 5\nheartbeat_ms = 0\nrevision_min = 1\nrevision_max = 1\n\n[[nodes]]\nid = 6\nheartbeat_ms = 50\n",
    )
    .unwrap();
    let settings = serve_args(&["--config", file.to_str().unwrap()])
        .unwrap()
        .settings_with(None)
        .unwrap();
    assert_eq!(settings.machine_nodes["demo"].len(), 2);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Issue 30, finding 7: a DCF of a `[[nodes]]` entry is read within a
/// bound: `/dev/zero` (not a regular file) and a file larger than an EDS
/// or DCF may be are refused at start with a clear error, unread.
#[test]
fn a_dcf_that_is_no_regular_file_or_too_large_is_refused_unread() {
    let dir = std::env::temp_dir().join(format!("candeck-dcf-bound-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("nodes.toml");
    let large = dir.join("large.dcf");
    // Sparse: its size without its bytes on disk.
    std::fs::File::create(&large)
        .unwrap()
        .set_len(crate::canopen::eds::MAX_FILE_BYTES + 1)
        .unwrap();
    for (dcf, expected) in [
        ("/dev/zero", "not a regular file"),
        (
            large.to_str().unwrap(),
            "more than the 16777216 an EDS or DCF may have",
        ),
    ] {
        std::fs::write(&file, format!("[[nodes]]\nid = 5\ndcf = \"{dcf}\"\n")).unwrap();
        let err = serve_args(&["--config", file.to_str().unwrap()])
            .unwrap()
            .settings_with(None)
            .unwrap_err();
        assert!(err.contains("config [[nodes]] id 5: DCF"), "{dcf}: {err}");
        assert!(err.contains(expected), "{dcf}: {err}");
    }
    // An EDS of the EDS directory too.
    let err = crate::canopen::eds::read_eds_file(&large).unwrap_err();
    assert!(err.to_string().contains("more than the"), "{err}");
    let err = crate::canopen::eds::read_eds_file("/dev/zero").unwrap_err();
    assert!(err.to_string().contains("not a regular file"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_heartbeat_consumer_factor_is_checked_for_its_range() {
    let dir = std::env::temp_dir().join(format!("candeck-factor-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let settings = |text: &str| {
        let file = dir.join("factor.toml");
        std::fs::write(&file, text).unwrap();
        serve_args(&["--config", file.to_str().unwrap()])
            .unwrap()
            .settings_with(None)
    };
    let default = settings("").unwrap();
    assert_eq!(default.machine.manager.consumer_factor.get(), 3.0);
    let two = settings("heartbeat_consumer_factor = 2.5\n").unwrap();
    assert_eq!(two.machine.manager.consumer_factor.get(), 2.5);
    for bad in ["1.0", "1.4", "10.5", "0", "-3"] {
        let err = settings(&format!("heartbeat_consumer_factor = {bad}\n")).unwrap_err();
        assert!(
            err.contains("heartbeat_consumer_factor") && err.contains("must be 1.5 to 10.0"),
            "{bad}: {err}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Issue 33, point 1: commands from MQTT need the broker to decide who may
/// send them: broker credentials, and TLS off loopback, or
/// `sparkplug_insecure = true`; the refusal names the settings.
#[test]
fn sparkplug_commands_need_broker_credentials_and_tls_off_loopback() {
    let dir = std::env::temp_dir().join(format!("candeck-sparkplug-auth-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("candeck.toml");
    let ca = dir.join("ca.pem");
    let settings = |text: &str| {
        std::fs::write(&file, format!("sparkplug_group_id = \"g\"\n{text}")).unwrap();
        serve_args(&["--config", file.to_str().unwrap()])
            .unwrap()
            .settings_with(None)
    };
    let operator = "sparkplug_role = \"operator\"\n";
    let login = "mqtt_username = \"line1\"\nmqtt_password = \"s3cret\"\n";
    // A viewer takes no command: nothing to refuse.
    assert!(settings("mqtt_url = \"mqtt://broker.plant\"\n").is_ok());
    for (text, missing) in [
        (
            format!("mqtt_url = \"mqtt://broker.plant\"\n{operator}"),
            "mqtt_username",
        ),
        (
            format!("mqtt_url = \"mqtt://broker.plant\"\n{operator}{login}"),
            "mqtts://",
        ),
        (
            format!("mqtt_url = \"mqtt://127.0.0.1:1883\"\n{operator}"),
            "mqtt_username",
        ),
    ] {
        let err = settings(&text).unwrap_err();
        assert!(err.contains(missing), "{text}: {err}");
        assert!(err.contains("sparkplug_insecure"), "{err}");
        // The override lets it start, with the warning to log.
        let config = settings(&format!("{text}sparkplug_insecure = true\n"))
            .unwrap()
            .sparkplug
            .unwrap();
        let warning = config.command_exposure().unwrap().unwrap();
        assert!(warning.contains("sparkplug_insecure = true"), "{warning}");
    }
    // Credentials on loopback, or credentials and TLS elsewhere: no warning.
    let config = settings(&format!(
        "mqtt_url = \"mqtt://localhost\"\n{operator}{login}"
    ))
    .unwrap()
    .sparkplug
    .unwrap();
    assert_eq!(config.command_exposure(), Ok(None));
    let config = settings(&format!(
        "mqtt_url = \"mqtts://broker.plant\"\nmqtt_ca_file = \"{}\"\n{operator}{login}",
        ca.display()
    ))
    .unwrap()
    .sparkplug
    .unwrap();
    assert_eq!(config.command_exposure(), Ok(None));
    std::fs::remove_dir_all(&dir).unwrap();
}
