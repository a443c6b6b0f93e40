use super::*;

#[test]
fn every_documented_spec_parses_and_prints_back() {
    let cases = [
        (
            "virtual:demo",
            BusSpec::Virtual {
                preset: "demo".into(),
                bitrate: None,
            },
        ),
        (
            "virtual:empty",
            BusSpec::Virtual {
                preset: "empty".into(),
                bitrate: None,
            },
        ),
        (
            "virtual:demo?bitrate=125000",
            BusSpec::Virtual {
                preset: "demo".into(),
                bitrate: Some(Bitrate::bits_per_second(125_000)),
            },
        ),
        (
            "virtual:empty?bitrate=unlimited",
            BusSpec::Virtual {
                preset: "empty".into(),
                bitrate: Some(Bitrate::Unlimited),
            },
        ),
        (
            "virtual:umc1bds32@1,uio1led@lss",
            BusSpec::Virtual {
                preset: "umc1bds32@1,uio1led@lss".into(),
                bitrate: None,
            },
        ),
        // Issue 32: a UMC's load in the bus spec, as `--devices` takes it.
        (
            "virtual:umc1bds32@1?inertia=0.001&friction=0.0002,jmc@2",
            BusSpec::Virtual {
                preset: "umc1bds32@1?inertia=0.001&friction=0.0002,jmc@2".into(),
                bitrate: None,
            },
        ),
        (
            "virtual:jmc@2,umc1bds32@1?inertia=0.001&bitrate=125000",
            BusSpec::Virtual {
                preset: "jmc@2,umc1bds32@1?inertia=0.001".into(),
                bitrate: Some(Bitrate::bits_per_second(125_000)),
            },
        ),
        (
            "virtual:umc1bds32@1?friction=0.0002,jmc@2?bitrate=unlimited",
            BusSpec::Virtual {
                preset: "umc1bds32@1?friction=0.0002,jmc@2".into(),
                bitrate: Some(Bitrate::Unlimited),
            },
        ),
        (
            "socketcan:can0",
            BusSpec::Socketcan {
                interface: "can0".into(),
            },
        ),
        (
            "socketcand:127.0.0.1:29536/can0",
            BusSpec::Socketcand {
                host: "127.0.0.1".into(),
                port: 29536,
                channel: "can0".into(),
            },
        ),
        (
            "socketcand:vbus:29536/can0",
            BusSpec::Socketcand {
                host: "vbus".into(),
                port: 29536,
                channel: "can0".into(),
            },
        ),
        (
            "socketcand:[::1]:29536/vcan0",
            BusSpec::Socketcand {
                host: "::1".into(),
                port: 29536,
                channel: "vcan0".into(),
            },
        ),
        (
            "replay:logs/line.log",
            BusSpec::Replay {
                path: "logs/line.log".into(),
                options: None,
            },
        ),
        (
            "replay:line.log?speed=4&loop",
            BusSpec::Replay {
                path: "line.log".into(),
                options: Some("speed=4&loop".into()),
            },
        ),
    ];
    for (text, spec) in cases {
        assert_eq!(text.parse::<BusSpec>(), Ok(spec.clone()), "{text}");
        assert_eq!(spec.to_string(), text);
    }
}

#[test]
fn bad_specs_say_what_is_expected() {
    let cases = [
        ("can0", "bus spec 'can0' is not one of"),
        ("serial:ttyUSB0", "bus spec 'serial:ttyUSB0' is not one of"),
        (
            "virtual:other",
            "a virtual bus is 'virtual:demo', 'virtual:empty' or a device list",
        ),
        ("virtual:demo?bitrate=fast", "bit rate 'fast' is not"),
        ("virtual:demo?speed=2", "?bitrate=N|unlimited"),
        // A load is a device's, and a number; the bit rate the bus's, once.
        ("virtual:demo?inertia=0.001", "?bitrate=N|unlimited"),
        (
            "virtual:umc1bds32@1?inertia=heavy",
            "inertia 'heavy' of umc1bds32@1 is not a number",
        ),
        (
            "virtual:umc1bds32@1?mass=2",
            "each device of a list ?inertia=KGM2&friction=NMS",
        ),
        (
            "virtual:umc1bds32@1?bitrate=125k,jmc@2",
            "bitrate is the bus's option, given once after the last device",
        ),
        (
            "virtual:umc1bds32@1?bitrate=125k&bitrate=250k",
            "bitrate is the bus's option, given once",
        ),
        ("socketcan:", "expected a network interface name"),
        (
            "socketcan:averyveryverylongname",
            "expected a network interface name",
        ),
        (
            "socketcand:localhost",
            "expected socketcand:HOST:PORT/CHANNEL",
        ),
        (
            "socketcand:localhost/can0",
            "expected socketcand:HOST:PORT/CHANNEL",
        ),
        (
            "socketcand::29536/can0",
            "expected socketcand:HOST:PORT/CHANNEL",
        ),
        ("socketcand:localhost:0/can0", "port '0' is not 1 to 65535"),
        (
            "socketcand:localhost:99999/can0",
            "port '99999' is not 1 to 65535",
        ),
        ("socketcand:localhost:1/", "the channel is a bus name"),
        ("replay:", "expected replay:FILE"),
    ];
    for (text, expected) in cases {
        let err = text.parse::<BusSpec>().expect_err(text).to_string();
        assert!(err.contains(expected), "{text}: {err}");
    }
}

#[test]
fn default_names_follow_the_api() {
    let name = |s: &str| s.parse::<BusSpec>().unwrap().default_name();
    assert_eq!(name("virtual:demo"), "demo");
    assert_eq!(name("socketcan:can1"), "can1");
    assert_eq!(name("socketcand:h:1/can0"), "can0");
    assert_eq!(name("replay:/tmp/line-3.log?loop"), "line-3");
}

#[tokio::test]
async fn an_empty_virtual_bus_opens_with_its_hub() {
    let opened = "virtual:empty"
        .parse::<BusSpec>()
        .unwrap()
        .open("line")
        .await
        .unwrap();
    assert_eq!(opened.bus.name(), "line");
    assert!(opened.hub.is_some());
    // 500 kbit/s unless told; the spec's own rate before the opener's.
    assert_eq!(opened.hub.unwrap().bitrate(), Bitrate::default());
    let spec = "virtual:empty?bitrate=125k".parse::<BusSpec>().unwrap();
    let opened = spec
        .open_with_bitrate("line", Bitrate::Unlimited)
        .await
        .unwrap();
    assert_eq!(opened.hub.unwrap().bitrate().get(), Some(125_000));
    let spec = "virtual:empty".parse::<BusSpec>().unwrap();
    let opened = spec
        .open_with_bitrate("line", Bitrate::Unlimited)
        .await
        .unwrap();
    assert_eq!(opened.hub.unwrap().bitrate(), Bitrate::Unlimited);
}

#[cfg(not(feature = "socketcan"))]
#[tokio::test]
async fn socketcan_without_the_feature_says_how_to_get_it() {
    let err = "socketcan:can0"
        .parse::<BusSpec>()
        .unwrap()
        .open("can0")
        .await
        .unwrap_err();
    assert!(err.to_string().contains("--features socketcan"), "{err}");
}
