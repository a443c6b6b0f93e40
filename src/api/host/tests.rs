use super::*;

#[test]
fn loopback_addresses_and_listed_names_pass() {
    let hosts = AllowedHosts::new(&["Gateway.Plant.example.".to_string()]).unwrap();
    for host in [
        "localhost",
        "localhost:8080",
        "LOCALHOST.:8080",
        "ui.localhost:1",
        "127.0.0.1:8080",
        "127.3.2.1",
        "[::1]:8080",
        "[::1]",
        "192.0.2.7:8080",
        "gateway.plant.example:8443",
        "gateway.plant.example",
    ] {
        assert!(hosts.allows(host), "{host}");
    }
    for host in [
        "evil.example:8080",
        "evil.example",
        "localhost.evil.example",
        "gateway.plant.example.evil",
        "",
        "localhost:80:80",
        "[::1]x",
        "localhost:http",
    ] {
        assert!(!hosts.allows(host), "{host}");
    }
    assert!(
        AllowedHosts::new(&["*".to_string()])
            .unwrap()
            .allows("evil.example:8080")
    );
}

#[test]
fn entries_that_are_no_host_names_are_refused() {
    for entry in ["http://gateway", "gateway:8080", "gateway/x", ""] {
        let err = AllowedHosts::new(&[entry.to_string()]).unwrap_err();
        assert!(err.contains("no host name"), "{entry}: {err}");
    }
}
