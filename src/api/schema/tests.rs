//! Each mirror against the gateway values it describes: their JSON checked
//! against its schema in the served document, and every property and enum
//! value of it met by one of them (see the module documentation).

use std::collections::BTreeSet;

use serde::Serialize;
use serde::de::DeserializeOwned;
use serde_json::{Map, Value as Json, json};
use utoipa::ToSchema;

use crate::api::auth::WhoAmI;
use crate::api::drives::{
    AxisDetail, MotionResponse, StateResponse, StopAllReport, StopFailure, StoppedAxis,
};
use crate::api::segments::SegmentState;
use crate::gateway::Role;
use crate::gateway::{AxisLimits, AxisStatus, AxisUnits, MoveMode, MoveRequest, TargetState};
use crate::gateway::{
    ChannelInfo, ChannelRequest, LoggerRequest, LoggerState, LoggerStatus, Source,
};
use crate::gateway::{Color, Preview, PreviewSegment};
use crate::gateway::{
    LoopGains, SampleSource, Sampling, StepLoop, StepTestRequest, StepTestResult,
};
use crate::gateway::{StopAttempt, StopMethod, StopOutcome};

/// Every variant of a gateway enum of unit variants. Fails to compile when
/// the enum gains one, so that its mirror is checked for it too.
macro_rules! every {
    ($enum:ident { $($variant:ident),+ $(,)? }) => {{
        let _exhaustive = |value: $enum| match value {
            $($enum::$variant)|+ => {}
        };
        [$($enum::$variant),+]
    }};
}

/// The served document's schemas, and the places of them (`Name.field`,
/// `Name=value`, `Name/oneOf/N`) the values checked so far met.
struct Checker {
    schemas: Map<String, Json>,
    met: BTreeSet<String>,
}

impl Checker {
    fn new() -> Self {
        let document = serde_json::to_value(crate::api::doc::openapi()).unwrap();
        let schemas = document["components"]["schemas"]
            .as_object()
            .expect("the document has schemas")
            .clone();
        Self {
            schemas,
            met: BTreeSet::new(),
        }
    }

    /// Checks the JSON `value` serializes to against the schema `M` (a
    /// mirror, or a body of the door's that holds gateway types).
    fn check<M: ToSchema>(&mut self, value: &impl Serialize) {
        let name = M::name();
        let json = serde_json::to_value(value).unwrap();
        let reference = json!({ "$ref": format!("#/components/schemas/{name}") });
        let mut met = BTreeSet::new();
        if let Err(err) = self.conforms(&json, &reference, &name, &mut met) {
            panic!("{json} is not what schema {name} describes: {err}");
        }
        self.met.extend(met);
    }

    /// [`Self::check`] for a value the gateway also takes: what it
    /// serializes to reads back as the same value.
    fn check_taken<M: ToSchema, T: Serialize + DeserializeOwned>(&mut self, value: &T) {
        self.check::<M>(value);
        let json = serde_json::to_value(value).unwrap();
        let back: T = serde_json::from_value(json.clone())
            .unwrap_or_else(|err| panic!("{json} does not read back: {err}"));
        assert_eq!(serde_json::to_value(&back).unwrap(), json);
    }

    /// The examples of schema `M` (its own, or each of its `oneOf`'s):
    /// the gateway takes them as `T`.
    fn examples_are_taken<M: ToSchema, T: DeserializeOwned>(&self) {
        let schema = &self.schemas[M::name().as_ref()];
        let mut examples: Vec<&Json> = schema.get("example").into_iter().collect();
        if let Some(branches) = schema.get("oneOf").and_then(Json::as_array) {
            examples.extend(branches.iter().filter_map(|branch| branch.get("example")));
        }
        assert!(!examples.is_empty(), "{} has no example", M::name());
        for example in examples {
            if let Err(err) = serde_json::from_value::<T>(example.clone()) {
                panic!("the gateway does not take the example {example}: {err}");
            }
        }
    }

    /// Every property, enum value and `oneOf` branch of each schema `names`
    /// was met by a value checked.
    fn covered(&self, names: &[std::borrow::Cow<'static, str>]) {
        let mut missing = Vec::new();
        for name in names {
            let schema = self
                .schemas
                .get(name.as_ref())
                .unwrap_or_else(|| panic!("the document has no schema {name}"));
            let mut places = BTreeSet::new();
            places_of(schema, name, &mut places);
            missing.extend(places.difference(&self.met).cloned());
        }
        assert!(
            missing.is_empty(),
            "no value checked met {missing:?}: a mirror describes more than its gateway type \
             (or the tests lack a value)"
        );
    }

    /// Whether `value` is what `schema` describes; `at` names the place,
    /// `met` gathers the places met.
    fn conforms(
        &self,
        value: &Json,
        schema: &Json,
        at: &str,
        met: &mut BTreeSet<String>,
    ) -> Result<(), String> {
        if let Some(reference) = schema.get("$ref").and_then(Json::as_str) {
            let name = reference
                .strip_prefix("#/components/schemas/")
                .ok_or_else(|| format!("{at}: reference {reference}"))?;
            let target = self
                .schemas
                .get(name)
                .ok_or_else(|| format!("{at}: no schema {name}"))?;
            return self.conforms(value, target, name, met);
        }
        if let Some(branches) = schema.get("oneOf").and_then(Json::as_array) {
            let mut matched = Vec::new();
            let mut errors = Vec::new();
            for (n, branch) in branches.iter().enumerate() {
                let place = format!("{at}/oneOf/{n}");
                let mut branch_met = BTreeSet::new();
                match self.conforms(value, branch, &place, &mut branch_met) {
                    Ok(()) => {
                        branch_met.insert(place);
                        matched.push(branch_met);
                    }
                    Err(err) => errors.push(err),
                }
            }
            return match matched.len() {
                1 => {
                    met.extend(matched.remove(0));
                    Ok(())
                }
                0 => Err(format!("{at}: no branch of oneOf: {}", errors.join("; "))),
                n => Err(format!("{at}: {n} branches of oneOf match {value}")),
            };
        }
        if let Some(types) = schema.get("type") {
            let types: Vec<&str> = match types {
                Json::Array(types) => types.iter().filter_map(Json::as_str).collect(),
                other => other.as_str().into_iter().collect(),
            };
            if !types.iter().any(|kind| is_of_type(value, kind)) {
                return Err(format!("{at}: {value} is no {types:?}"));
            }
        }
        if let Some(values) = schema.get("enum").and_then(Json::as_array) {
            if !values.contains(value) {
                return Err(format!("{at}: {value} is none of {values:?}"));
            }
            met.insert(format!("{at}={value}"));
        }
        if let Some(number) = value.as_f64() {
            let below = schema
                .get("minimum")
                .and_then(Json::as_f64)
                .is_some_and(|minimum| number < minimum);
            let above = schema
                .get("maximum")
                .and_then(Json::as_f64)
                .is_some_and(|maximum| number > maximum);
            if below || above {
                return Err(format!("{at}: {value} is out of the schema's range"));
            }
        }
        if let (Some(items), Some(array)) = (schema.get("items"), value.as_array()) {
            for item in array {
                self.conforms(item, items, &format!("{at}[]"), met)?;
            }
        }
        if let Some(object) = value.as_object() {
            let mut parts = Vec::new();
            self.object_parts(schema, at, &mut parts)?;
            if parts.is_empty() {
                return Err(format!("{at}: {value} is an object, the schema none"));
            }
            for (place, part) in &parts {
                let required = part.get("required").and_then(Json::as_array);
                for key in required.into_iter().flatten().filter_map(Json::as_str) {
                    if !object.contains_key(key) {
                        return Err(format!("{place}: `{key}` is required, missing"));
                    }
                }
            }
            for (key, field) in object {
                let found = parts.iter().find_map(|(place, part)| {
                    let property = part.get("properties")?.get(key)?;
                    Some((format!("{place}.{key}"), property))
                });
                let Some((place, property)) = found else {
                    return Err(format!("{at}: `{key}` is no property of the schema"));
                };
                self.conforms(field, property, &place, met)?;
                met.insert(place);
            }
        }
        Ok(())
    }

    /// The object schemas `schema` is made of (itself, what it refers to,
    /// the parts of its `allOf`), each with its place.
    fn object_parts<'a>(
        &'a self,
        schema: &'a Json,
        at: &str,
        parts: &mut Vec<(String, &'a Json)>,
    ) -> Result<(), String> {
        if let Some(reference) = schema.get("$ref").and_then(Json::as_str) {
            let name = reference.trim_start_matches("#/components/schemas/");
            let target = self
                .schemas
                .get(name)
                .ok_or_else(|| format!("{at}: no schema {name}"))?;
            return self.object_parts(target, name, parts);
        }
        if let Some(all) = schema.get("allOf").and_then(Json::as_array) {
            for part in all {
                self.object_parts(part, at, parts)?;
            }
        }
        if schema.get("properties").is_some() {
            parts.push((at.to_string(), schema));
        }
        Ok(())
    }
}

fn is_of_type(value: &Json, kind: &str) -> bool {
    match kind {
        "null" => value.is_null(),
        "boolean" => value.is_boolean(),
        "integer" => value.is_i64() || value.is_u64(),
        "number" => value.is_number(),
        "string" => value.is_string(),
        "array" => value.is_array(),
        "object" => value.is_object(),
        _ => false,
    }
}

/// The places of `schema` (named `at`) a value may meet: each property,
/// each enum value, each branch of a `oneOf` and its properties.
fn places_of(schema: &Json, at: &str, places: &mut BTreeSet<String>) {
    if let Some(properties) = schema.get("properties").and_then(Json::as_object) {
        places.extend(properties.keys().map(|key| format!("{at}.{key}")));
    }
    if let Some(values) = schema.get("enum").and_then(Json::as_array) {
        places.extend(values.iter().map(|value| format!("{at}={value}")));
    }
    if let Some(branches) = schema.get("oneOf").and_then(Json::as_array) {
        for (n, branch) in branches.iter().enumerate() {
            let place = format!("{at}/oneOf/{n}");
            places_of(branch, &place, places);
            places.insert(place);
        }
    }
}

fn axis_status(axis: u8, mode: Option<&str>) -> AxisStatus {
    AxisStatus {
        axis,
        state: "operation_enabled".into(),
        statusword: 0x0427,
        mode: mode.map(Into::into),
        mode_raw: 1,
        supported_modes: MoveMode::ALL.to_vec(),
        position: mode.map(|_| 65_536),
        velocity: mode.map(|_| -12),
        torque: mode.map(|_| 30),
        target_reached: true,
        fault: false,
    }
}

fn stop_attempts() -> Vec<StopAttempt> {
    let methods = every!(StopMethod {
        Halt,
        QuickStop,
        NmtStop
    });
    let outcomes = every!(StopOutcome {
        Confirmed,
        Sent,
        Timeout,
        SdoAbort,
        SdoProtocolError,
        BusDown,
        Skipped,
        Failed,
    });
    let mut attempts: Vec<StopAttempt> = outcomes
        .into_iter()
        .zip(methods.into_iter().cycle())
        .map(|(outcome, method)| StopAttempt {
            method,
            outcome,
            detail: Some("statusword 0x0007: quick_stop_active".into()),
        })
        .collect();
    attempts.push(StopAttempt {
        method: StopMethod::NmtStop,
        outcome: StopOutcome::Sent,
        detail: None,
    });
    attempts
}

#[test]
fn the_drive_mirrors_describe_the_gateways_axes_and_moves() {
    let mut checker = Checker::new();
    for mode in every!(MoveMode {
        ProfilePosition,
        Velocity,
        Torque,
        DutyCycle,
        ContinuousPosition,
        InterpolatedPosition,
        Homing,
    }) {
        checker.check_taken::<super::MoveMode, _>(&mode);
    }
    let moves = [
        MoveRequest::ProfilePosition {
            target: -65_536,
            relative: true,
            immediate: false,
            velocity: Some(1000),
            acceleration: Some(100),
            deceleration: Some(100),
        },
        MoveRequest::ProfilePosition {
            target: 65_536,
            relative: false,
            immediate: true,
            velocity: None,
            acceleration: None,
            deceleration: None,
        },
        MoveRequest::Velocity {
            velocity: -100,
            acceleration: Some(10),
            deceleration: Some(10),
        },
        MoveRequest::Torque {
            torque: 100,
            slope: Some(50),
        },
        MoveRequest::DutyCycle {
            duty: -8192,
            slope: Some(5),
        },
        MoveRequest::ContinuousPosition {
            target: 32_768,
            relative: true,
        },
        MoveRequest::InterpolatedPosition {
            period_ms: 10,
            points: vec![0, 1000, 2000],
        },
        MoveRequest::Homing {
            method: -3,
            speeds: Some([100, 20]),
            acceleration: Some(10),
            offset: Some(-5),
        },
    ];
    // Fails to compile when the gateway has a move more: add it above.
    let _exhaustive = |request: &MoveRequest| match request {
        MoveRequest::ProfilePosition { .. }
        | MoveRequest::Velocity { .. }
        | MoveRequest::Torque { .. }
        | MoveRequest::DutyCycle { .. }
        | MoveRequest::ContinuousPosition { .. }
        | MoveRequest::InterpolatedPosition { .. }
        | MoveRequest::Homing { .. } => {}
    };
    let modes: BTreeSet<String> = moves.iter().map(|m| m.mode().to_string()).collect();
    assert_eq!(modes.len(), MoveMode::ALL.len(), "a move of each mode");
    for request in &moves {
        checker.check_taken::<super::MoveRequest, _>(request);
    }
    checker.examples_are_taken::<super::MoveRequest, MoveRequest>();
    for target in every!(TargetState {
        OperationEnabled,
        SwitchedOn,
        ReadyToSwitchOn,
        SwitchOnDisabled,
        QuickStopActive,
    }) {
        checker.check_taken::<super::TargetState, _>(&target);
    }
    let units = AxisUnits {
        position: "increments".into(),
        velocity: "increments/ms".into(),
        acceleration: "increments/ms²".into(),
        vl_velocity: Some("vl units".into()),
        rps_per_velocity_unit: Some(1000.0 / 65536.0),
        position_per_revolution: Some(65536.0),
        torque: "‰ of rated torque".into(),
    };
    let limits = AxisLimits {
        max_profile_velocity: Some(16_384),
        max_motor_speed: Some(16_384),
        profile_velocity: Some(100),
        profile_acceleration: Some(1),
        vl_min: Some(0),
        vl_max: Some(1000),
        vl_dimension_factor: Some([1, -1]),
        software_position_limit: Some([-1_000_000, 1_000_000]),
        encoder_resolution: Some([65_536, 1]),
        gear_ratio: Some([1, 1]),
    };
    for status in [
        axis_status(1, Some("profile_position")),
        axis_status(2, None),
    ] {
        checker.check::<super::AxisStatus>(&status);
    }
    checker.check::<super::AxisUnits>(&units);
    checker.check::<super::AxisUnits>(&AxisUnits {
        vl_velocity: None,
        rps_per_velocity_unit: None,
        position_per_revolution: None,
        ..units.clone()
    });
    checker.check::<super::AxisLimits>(&limits);
    checker.check::<super::AxisLimits>(&AxisLimits::default());
    // The door's bodies that hold them.
    checker.check::<AxisDetail>(&AxisDetail {
        status: axis_status(1, Some("velocity")),
        units,
        limits,
    });
    checker.check::<StateResponse>(&StateResponse {
        status: axis_status(1, Some("velocity")),
        attempts: Some(stop_attempts()),
    });
    checker.check::<MotionResponse>(&MotionResponse {
        status: axis_status(1, None),
        lease: None,
        attempts: None,
    });
    checker.covered(&[
        super::MoveMode::name(),
        super::MoveRequest::name(),
        super::TargetState::name(),
        super::AxisStatus::name(),
        super::AxisUnits::name(),
        super::AxisLimits::name(),
    ]);
}

#[test]
fn the_step_test_mirrors_describe_the_gateways_request_and_result() {
    let mut checker = Checker::new();
    for loop_ in every!(StepLoop {
        Torque,
        Velocity,
        Position
    }) {
        checker.check_taken::<super::StepTestRequest, _>(&StepTestRequest {
            loop_,
            from: -10,
            to: 500,
            hold_ms: 300,
            settle_band_pct: 2.5,
        });
    }
    checker.examples_are_taken::<super::StepTestRequest, StepTestRequest>();
    for (source, sampling) in every!(SampleSource {
        Tpdo,
        Sdo,
        TpdoThenSdo
    })
    .into_iter()
    .zip(every!(Sampling { Tpdo, Sdo }).into_iter().cycle())
    {
        checker.check::<super::StepTestResult>(&StepTestResult {
            sampling,
            sample_rate_hz: 1000.0,
            sampling_note: "TPDO 4 set up for the test".to_string(),
            source,
            rise_time_ms: Some(12.5),
            overshoot_pct: 3.0,
            settling_time_ms: Some(40.0),
            steady_state_error: -0.5,
            samples: vec![[0.0, 500.0, 0.0], [1.0, 500.0, 12.0]],
            gains: Some(LoopGains {
                p: 0.015,
                i: 0.4,
                d: 0.0,
            }),
        });
    }
    checker.check::<super::StepTestResult>(&StepTestResult {
        sampling: Sampling::Sdo,
        sample_rate_hz: 0.0,
        sampling_note: String::new(),
        source: SampleSource::Sdo,
        rise_time_ms: None,
        overshoot_pct: 0.0,
        settling_time_ms: None,
        steady_state_error: 500.0,
        samples: Vec::new(),
        gains: None,
    });
    checker.covered(&[
        super::StepLoop::name(),
        super::StepTestRequest::name(),
        super::SampleSource::name(),
        super::Sampling::name(),
        super::StepTestResult::name(),
        super::LoopGains::name(),
    ]);
}

#[test]
fn the_stop_mirrors_describe_the_gateways_attempts() {
    let mut checker = Checker::new();
    for attempt in stop_attempts() {
        checker.check::<super::StopAttempt>(&attempt);
    }
    // The door's bodies that hold them.
    checker.check::<StopAllReport>(&StopAllReport {
        stopped: vec![StoppedAxis {
            bus: "demo".into(),
            node: 1,
            axis: 1,
            attempts: stop_attempts(),
        }],
        failed: vec![StopFailure {
            bus: "demo".into(),
            node: 2,
            axis: None,
            error: json!({"code": "sdo_timeout", "message": "node 2 did not answer"}),
            attempts: stop_attempts(),
        }],
    });
    checker.covered(&[
        super::StopMethod::name(),
        super::StopOutcome::name(),
        super::StopAttempt::name(),
    ]);
}

#[test]
fn the_logger_mirrors_describe_the_gateways_request_and_status() {
    let mut checker = Checker::new();
    checker.check_taken::<super::LoggerRequest, _>(&LoggerRequest {
        channels: vec![
            ChannelRequest {
                bus: "demo".into(),
                node: 1,
                index: json!("0x6064"),
                sub: Some(json!("0")),
            },
            ChannelRequest {
                bus: "demo".into(),
                node: 127,
                index: json!("a1_pv_Velocity_actual_value"),
                sub: None,
            },
        ],
        period_ms: 10,
        duration_s: 2,
    });
    checker.examples_are_taken::<super::LoggerRequest, LoggerRequest>();
    let channel = |source: Option<Source>| ChannelInfo {
        bus: "demo".into(),
        node: 1,
        index: "0x6064".into(),
        sub: 0,
        name: "demo/1/a1_pc_Position_actual_value".into(),
        data_type: source.map(|_| "i32".into()),
        unit: source.map(|_| "increments".into()),
        source,
        sdo_samples: 3,
        tpdo_samples: 4,
        errors: 1,
        last_error: source.map(|_| "sdo_timeout".into()),
    };
    let states = every!(LoggerState {
        Running,
        Done,
        Stopped
    });
    for state in states {
        checker.check_taken::<super::LoggerStatus, _>(&LoggerStatus {
            id: 7,
            state,
            period_ms: 10,
            duration_s: 2,
            started_ms: 1_795_000_000_000,
            samples: 200,
            missed: 1,
            dropped: 0,
            rows: 199,
            persisted: state == LoggerState::Done,
            channels: every!(Source { Sdo, Tpdo })
                .into_iter()
                .map(Some)
                .chain([None])
                .map(channel)
                .collect(),
        });
    }
    checker.covered(&[
        super::ChannelRequest::name(),
        super::LoggerRequest::name(),
        super::Source::name(),
        super::ChannelInfo::name(),
        super::LoggerState::name(),
        super::LoggerStatus::name(),
    ]);
}

#[test]
fn the_role_mirror_describes_the_gateways_roles() {
    let mut checker = Checker::new();
    for role in every!(Role {
        Viewer,
        Operator,
        Admin
    }) {
        checker.check::<super::Role>(&role);
        checker.check::<WhoAmI>(&WhoAmI {
            name: "plc".into(),
            role,
            auth_required: true,
        });
    }
    checker.covered(&[super::Role::name()]);
}

#[test]
fn the_led_mirrors_describe_the_gateways_preview() {
    let mut checker = Checker::new();
    let red = Color {
        r: 255,
        g: 0,
        b: 0,
        w: 10,
    };
    checker.check_taken::<super::Color, _>(&red);
    checker.check::<super::Preview>(&Preview {
        led_count: 3,
        segments: vec![
            PreviewSegment {
                segment: 1,
                start: 0,
                led_count: 3,
                effect: "fix".into(),
            },
            PreviewSegment {
                segment: 2,
                start: 3,
                led_count: 0,
                effect: "0x0042".into(),
            },
        ],
        pixels: vec![red; 3],
    });
    // The door's body that holds them.
    checker.check::<SegmentState>(&SegmentState::new(1, &Default::default()));
    checker.covered(&[
        super::Color::name(),
        super::Preview::name(),
        super::PreviewSegment::name(),
    ]);
}
