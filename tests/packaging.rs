//! The packaging agrees with what the test command runs: the Dockerfile's
//! build and smoke steps are `scripts/container-steps` (which scripts/test
//! runs outside Docker), the compose services run the commands the smoke
//! test starts, and the settings only the config file or the packaging use
//! (`--sync-period-ms`) reach the running gateway.

mod common;

use std::path::Path;

fn read(path: &str) -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(path))
        .unwrap_or_else(|err| panic!("{path}: {err}"))
}

/// The Dockerfile's instructions, continuation lines joined, comments out.
fn dockerfile() -> Vec<String> {
    let text = read("Dockerfile");
    let mut instructions = Vec::new();
    let mut current = String::new();
    for line in text.lines() {
        let line = line.trim();
        if line.starts_with('#') || (line.is_empty() && current.is_empty()) {
            continue;
        }
        match line.strip_suffix('\\') {
            Some(part) => current.push_str(part.trim_end()),
            None => {
                current.push_str(line);
                instructions.push(std::mem::take(&mut current));
            }
        }
        if !current.is_empty() {
            current.push(' ');
        }
    }
    instructions
}

/// The words of a bash array assignment `NAME=(a b c)` in container-steps.
fn script_array(name: &str) -> Vec<String> {
    let script = read("scripts/container-steps");
    let prefix = format!("{name}=(");
    let line = script
        .lines()
        .find_map(|line| line.strip_prefix(&prefix))
        .unwrap_or_else(|| panic!("no {name} in scripts/container-steps"));
    line.trim_end_matches(')')
        .split_whitespace()
        .map(str::to_string)
        .collect()
}

/// A compose service's block: its lines below its name.
fn compose_service(service: &str) -> String {
    let compose = read("docker-compose.yml");
    let header = format!("  {service}:");
    let start = compose
        .lines()
        .position(|line| line == header)
        .unwrap_or_else(|| panic!("no service {service}"));
    compose
        .lines()
        .skip(start + 1)
        .take_while(|line| line.is_empty() || line.starts_with("    "))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The `command:` list of a compose service (a flow sequence of quoted
/// strings, which is JSON).
fn compose_command(service: &str) -> Vec<String> {
    let block = compose_service(service);
    let line = block
        .lines()
        .find_map(|line| line.trim().strip_prefix("command: "))
        .unwrap_or_else(|| panic!("service {service} has no command"));
    serde_json::from_str(line).unwrap_or_else(|err| panic!("{service}: {err}: {line}"))
}

fn without(args: &[String], options: &[&str]) -> Vec<String> {
    let mut kept = Vec::new();
    let mut words = args.iter();
    while let Some(word) = words.next() {
        if options.contains(&word.as_str()) {
            words.next();
        } else {
            kept.push(word.clone());
        }
    }
    kept
}

#[test]
fn the_dockerfile_builds_and_checks_with_the_scripts_steps() {
    let instructions = dockerfile();
    let steps: Vec<&str> = instructions
        .iter()
        .filter_map(|line| line.strip_prefix("RUN scripts/container-steps "))
        .collect();
    assert_eq!(steps, ["build", "install", "smoke dist/candeck"]);
    let script = read("scripts/container-steps");
    assert!(
        script
            .contains("\n    cargo build --release --locked --features socketcan --bin candeck\n")
    );

    let has = |wanted: &str| instructions.iter().any(|line| line == wanted);
    assert!(has(
        "COPY --from=build /src/dist/candeck /usr/local/bin/candeck"
    ));
    assert!(has(r#"ENTRYPOINT ["candeck"]"#));
    assert!(has("EXPOSE 8080 29536"));
    assert!(has(r#"VOLUME ["/var/lib/candeck"]"#));
    // A fixed, non-root user.
    assert!(has("USER 10001:10001"));
    let healthcheck = instructions
        .iter()
        .find(|line| line.starts_with("HEALTHCHECK "))
        .expect("a HEALTHCHECK");
    assert!(
        healthcheck.contains("http://127.0.0.1:8080/api/v1/health"),
        "{healthcheck}"
    );
    // Base images pinned to a release, apt lists cleaned, no recommends.
    for from in instructions.iter().filter(|line| line.starts_with("FROM ")) {
        assert!(!from.contains(":latest") && from.contains(':'), "{from}");
    }
    for run in instructions
        .iter()
        .filter(|line| line.contains("apt-get install"))
    {
        assert!(run.contains("--no-install-recommends"), "{run}");
        assert!(run.contains("rm -rf /var/lib/apt/lists/*"), "{run}");
    }
    // The image's default command is the gateway's, on its data volume.
    let cmd = instructions
        .iter()
        .find_map(|line| line.strip_prefix("CMD "))
        .expect("a CMD");
    let cmd: Vec<String> = serde_json::from_str(cmd).unwrap();
    assert_eq!(
        without(&cmd, &["--listen"]),
        ["serve", "--data-dir", "/var/lib/candeck", "--insecure"]
    );
}

#[test]
fn the_compose_services_run_what_the_smoke_test_runs() {
    // The smoke test picks its own addresses; the rest is the same.
    let vbus = compose_command("vbus");
    assert_eq!(without(&vbus, &["--listen"]), script_array("VBUS_ARGS"));
    assert!(
        vbus.windows(2)
            .any(|pair| pair == ["--listen", "0.0.0.0:29536"])
    );

    let gateway = compose_command("gateway");
    let mut served = without(
        &gateway,
        &["--listen", "--bus", "--data-dir", "--opcua-listen"],
    );
    served.push("--data-dir".to_string());
    let mut smoke = script_array("SERVE_ARGS");
    served.sort();
    smoke.sort();
    assert_eq!(served, smoke);
    assert!(
        gateway
            .windows(2)
            .any(|pair| pair == ["--bus", "line=socketcand:vbus:29536/can0"])
    );
    assert!(
        gateway
            .windows(2)
            .any(|pair| pair == ["--listen", "0.0.0.0:8080"])
    );
    // OPC UA on every address of the container, published on the host's
    // loopback (the smoke test serves it on a free port).
    assert!(
        gateway
            .windows(2)
            .any(|pair| pair == ["--opcua-listen", "0.0.0.0:4840"])
    );
    assert!(
        compose_service("gateway").contains("\"127.0.0.1:4840:4840\""),
        "the OPC UA port is published on loopback only"
    );

    // The real-bus profile: SocketCAN, tokens from the environment.
    let can = compose_command("can-gateway");
    assert!(
        can.windows(2)
            .any(|pair| pair == ["--bus", "line=socketcan:can0"])
    );
    assert!(!can.contains(&"--insecure".to_string()));
}

#[tokio::test]
async fn the_sync_period_of_the_command_line_runs_from_the_start() {
    let (server, _) = common::start(&["serve", "--sync-period-ms", "25"]);
    let (status, sync) =
        common::json(&server.address, "GET", "/api/v1/buses/demo/sync", None).await;
    assert_eq!(status, 200, "{sync}");
    assert_eq!(sync["period_ms"], 25);
    // It sends: the counter moves (however fast this machine is).
    let (_, sent) = common::poll(&server.address, "/api/v1/buses/demo/sync", |_, sync| {
        sync["sent"].as_u64().unwrap_or(0) > 0
    })
    .await;
    assert!(sent["sent"].as_u64().unwrap() > 0, "{sent}");
}
