//! The products candeck emulates and the `--devices` lists that put them on
//! a bus (`docs/cli.md`: `demo`, `none`, or `umc1bds32@1,jmc@2,uio1led@3`;
//! `uio1led@lss` or `uio1led@lss/SERIAL` for a device with no node-ID yet,
//! which waits for an LSS master, CiA 305).

use std::fmt;
use std::sync::{Arc, OnceLock};

use crate::canopen::NodeId;
use crate::canopen::eds::Eds;
use crate::canopen::od::ObjectDictionary;
use crate::profiles::builtin;

use super::behaviour::Behaviour;
use super::device::DeviceCore;
use super::io401::Io401;
use super::jmc::Jmc;
use super::objects::add_dummy_objects;
use super::uioled::Uioled;
use super::umc::{Load, Umc};

/// A product candeck can emulate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Product {
    /// UniSwarm UMC1BDS32, two-axis motion controller.
    Umc1bds32,
    /// UniSwarm UMC1BD90, motion controller.
    Umc1bd90,
    /// JMC CANopen stepper drive.
    Jmc,
    /// UniSwarm UIO1LED, LED strip controller.
    Uio1led,
    /// candeck io401, a CiA 401 generic I/O module (not in the demo).
    Io401,
}

impl Product {
    pub const ALL: [Product; 5] = [
        Self::Umc1bds32,
        Self::Umc1bd90,
        Self::Jmc,
        Self::Uio1led,
        Self::Io401,
    ];

    /// The name of `--devices` and of `POST /sim/nodes`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Umc1bds32 => "umc1bds32",
            Self::Umc1bd90 => "umc1bd90",
            Self::Jmc => "jmc",
            Self::Uio1led => "uio1led",
            Self::Io401 => "io401",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|product| product.name().eq_ignore_ascii_case(name.trim()))
    }

    /// The built-in EDS, written from the product's manual.
    pub fn eds_text(self) -> &'static str {
        match self {
            Self::Umc1bds32 => builtin::UMC1BDS32,
            Self::Umc1bd90 => builtin::UMC1BD90,
            Self::Jmc => builtin::JMC_STEPPER,
            Self::Uio1led => builtin::UIO1LED,
            Self::Io401 => builtin::IO401,
        }
    }

    /// Whether the product answers an LSS master (CiA 305) as it comes:
    /// not the JMC, whose manual sets the node-ID by rotary switches and
    /// has no LSS. `PRODUCT@lss` is a device that does, whatever the
    /// product (the LSS demos' unconfigured devices).
    pub fn answers_lss(self) -> bool {
        match self {
            Self::Jmc => crate::profiles::jmc::ANSWERS_LSS,
            Self::Umc1bds32 | Self::Umc1bd90 | Self::Uio1led | Self::Io401 => true,
        }
    }

    /// The product's application.
    pub fn behaviour(self) -> Box<dyn Behaviour> {
        self.behaviour_with(None)
    }

    /// Whether the product drives motors: only these take a `load`.
    pub fn has_motors(self) -> bool {
        matches!(self, Self::Umc1bds32 | Self::Umc1bd90)
    }

    /// The product's application, its motors driving `load` (the default
    /// where `None`; only a product with motors has one).
    fn behaviour_with(self, load: Option<Load>) -> Box<dyn Behaviour> {
        let load = load.unwrap_or(Load::DEFAULT);
        match self {
            Self::Umc1bds32 => Box::new(Umc::with_load(2, load)),
            Self::Umc1bd90 => Box::new(Umc::with_load(1, load)),
            Self::Jmc => Box::new(Jmc::new()),
            Self::Uio1led => Box::new(Uioled::new()),
            Self::Io401 => Box::new(Io401::new()),
        }
    }

    /// The dictionary of the built-in EDS, read once and shared by every
    /// device of the product.
    pub fn dictionary(self) -> Result<Arc<ObjectDictionary>, String> {
        static PARSED: [OnceLock<Result<Arc<ObjectDictionary>, String>>; Product::ALL.len()] =
            [const { OnceLock::new() }; Product::ALL.len()];
        PARSED[self as usize]
            .get_or_init(|| {
                let file = format!("{}.eds (built in)", self.name());
                Eds::parse(self.eds_text(), &file)
                    .map(|eds| {
                        let mut dictionary = eds.dictionary;
                        add_dummy_objects(&mut dictionary, &eds.dummy_usage);
                        Arc::new(dictionary)
                    })
                    .map_err(|err| err.to_string())
            })
            .clone()
    }

    /// A device of this product at `node`, not booted yet.
    pub fn device(self, node: NodeId) -> Result<DeviceCore, String> {
        self.device_with_load(node, None)
    }

    /// A device of this product at `node` whose motors drive `load` (the
    /// default where `None`).
    pub fn device_with_load(self, node: NodeId, load: Option<Load>) -> Result<DeviceCore, String> {
        DeviceCore::with_behaviour(self.dictionary()?, node, self.behaviour_with(load))
            .map_err(|err| format!("{}.eds (built in): {err}", self.name()))
    }
}

impl fmt::Display for Product {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One device of a `--devices` list.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceSpec {
    pub product: Product,
    /// `None`: an unconfigured LSS slave (`@lss`).
    pub node: Option<NodeId>,
    /// The serial number (0x1018 sub 4) `@lss/SERIAL` gives; otherwise the
    /// rack picks one (see [`super::rack::Rack::add_spec`]).
    pub serial: Option<u32>,
    /// What its motors drive (`?inertia=KGM2&friction=NMS`); `None`: the
    /// default load ([`Load::DEFAULT`]).
    pub load: Option<Load>,
}

impl DeviceSpec {
    /// A device at `node`.
    pub fn at(product: Product, node: NodeId) -> Self {
        Self {
            product,
            node: Some(node),
            serial: None,
            load: None,
        }
    }

    /// The same device driving `load` (given as inertia, kg·m², and
    /// viscous friction, N·m·s, the default where `None`); an error when
    /// the product has no motors or a value is out of range.
    pub fn with_load(self, inertia: Option<f64>, friction: Option<f64>) -> Result<Self, String> {
        if inertia.is_none() && friction.is_none() {
            return Ok(self);
        }
        if !self.product.has_motors() {
            return Err(format!(
                "{} drives no motor: inertia and friction are options of umc1bds32 and umc1bd90",
                self.product
            ));
        }
        Ok(Self {
            load: Some(Load::new(inertia, friction)?),
            ..self
        })
    }
}

impl fmt::Display for DeviceSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.node, self.serial) {
            (Some(node), _) => write!(f, "{}@{}", self.product, node)?,
            (None, None) => write!(f, "{}@lss", self.product)?,
            (None, Some(serial)) => write!(f, "{}@lss/{serial}", self.product)?,
        }
        match self.load {
            Some(load) => write!(f, "?inertia={}&friction={}", load.inertia, load.friction),
            None => Ok(()),
        }
    }
}

/// The demo: node 1 a UMC1BDS32, node 2 a JMC stepper, node 3 a UIO1LED.
pub fn demo() -> Vec<DeviceSpec> {
    [
        (Product::Umc1bds32, 1),
        (Product::Jmc, 2),
        (Product::Uio1led, 3),
    ]
    .into_iter()
    .map(|(product, node)| DeviceSpec::at(product, NodeId::new(node).expect("1 to 3 are node ids")))
    .collect()
}

/// A whole `--devices` list, as one value of the command line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceList(pub Vec<DeviceSpec>);

impl std::str::FromStr for DeviceList {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        parse_devices(text).map(DeviceList)
    }
}

impl fmt::Display for DeviceList {
    /// `none`, or the list as `--devices` takes it.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0.is_empty() {
            return f.write_str("none");
        }
        let names: Vec<String> = self.0.iter().map(ToString::to_string).collect();
        f.write_str(&names.join(","))
    }
}

/// Reads `demo`, `none` (or `empty`, the bus spec's `virtual:empty`) or
/// `product@id,product@lss,product@lss/serial,...`, each device optionally
/// followed by `?inertia=KGM2&friction=NMS` (a UMC's load, either key or
/// both).
pub fn parse_devices(text: &str) -> Result<Vec<DeviceSpec>, String> {
    match text.trim() {
        "demo" => return Ok(demo()),
        "none" | "empty" | "" => return Ok(Vec::new()),
        _ => {}
    }
    let names: Vec<&str> = Product::ALL.iter().map(|p| p.name()).collect();
    let mut devices: Vec<DeviceSpec> = Vec::new();
    for item in text.split(',') {
        let (device, options) = match item.split_once('?') {
            Some((device, options)) => (device, Some(options)),
            None => (item, None),
        };
        let (product, node) = device.trim().split_once('@').ok_or_else(|| {
            format!(
                "'{item}' is not PRODUCT@NODE (for example jmc@2, or jmc@lss for an \
                 unconfigured LSS device); products: {}",
                names.join(", ")
            )
        })?;
        let product = Product::from_name(product).ok_or_else(|| {
            format!(
                "unknown product '{product}'; products: {}",
                names.join(", ")
            )
        })?;
        let node = node.trim();
        let spec = match node.strip_prefix("lss") {
            Some("") => DeviceSpec {
                product,
                node: None,
                serial: None,
                load: None,
            },
            Some(serial) => {
                let serial = serial.strip_prefix('/').ok_or_else(|| {
                    format!("'{item}': an LSS device is PRODUCT@lss or PRODUCT@lss/SERIAL")
                })?;
                let parsed = match serial
                    .strip_prefix("0x")
                    .or_else(|| serial.strip_prefix("0X"))
                {
                    Some(hex) => u32::from_str_radix(hex, 16),
                    None => serial.parse::<u32>(),
                };
                let serial = parsed.map_err(|_| {
                    format!("'{item}': serial number '{serial}' is not a 32-bit number")
                })?;
                DeviceSpec {
                    product,
                    node: None,
                    serial: Some(serial),
                    load: None,
                }
            }
            None => DeviceSpec::at(
                product,
                node.parse().map_err(|err| format!("'{item}': {err}"))?,
            ),
        };
        let spec = match options {
            Some(options) => {
                with_options(spec, options).map_err(|err| format!("'{item}': {err}"))?
            }
            None => spec,
        };
        if let Some(node) = spec.node
            && let Some(taken) = devices.iter().find(|d| d.node == Some(node))
        {
            return Err(format!("node {node} is given twice ({taken} and {item})"));
        }
        if let Some(serial) = spec.serial
            && let Some(taken) = devices
                .iter()
                .find(|d| d.product == product && d.serial == Some(serial))
        {
            return Err(format!(
                "serial number {serial} is given twice ({taken} and {item})"
            ));
        }
        devices.push(spec);
    }
    Ok(devices)
}

/// `spec` with the options after its `?`: `inertia=KGM2&friction=NMS`.
fn with_options(spec: DeviceSpec, options: &str) -> Result<DeviceSpec, String> {
    let (mut inertia, mut friction) = (None, None);
    for option in options.split('&') {
        let (key, value) = option
            .split_once('=')
            .ok_or_else(|| format!("option '{option}' is not KEY=VALUE (inertia, friction)"))?;
        let number = value
            .trim()
            .parse::<f64>()
            .map_err(|_| format!("{key} '{value}' is not a number"))?;
        let slot = match key.trim() {
            "inertia" => &mut inertia,
            "friction" => &mut friction,
            other => {
                return Err(format!(
                    "unknown option '{other}': a device takes inertia (kg·m²) and friction (N·m·s)"
                ));
            }
        };
        if slot.replace(number).is_some() {
            return Err(format!("{key} is given twice"));
        }
    }
    spec.with_load(inertia, friction)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(product: Product, node: u8) -> DeviceSpec {
        DeviceSpec::at(product, NodeId::new(node).unwrap())
    }

    #[test]
    fn lss_devices_in_a_list() {
        let devices = parse_devices("umc1bds32@1,uio1led@lss,jmc@lss/0x1F").unwrap();
        assert_eq!(
            devices,
            vec![
                spec(Product::Umc1bds32, 1),
                DeviceSpec {
                    product: Product::Uio1led,
                    node: None,
                    serial: None,
                    load: None,
                },
                DeviceSpec {
                    product: Product::Jmc,
                    node: None,
                    serial: Some(31),
                    load: None,
                },
            ]
        );
        assert_eq!(
            DeviceList(devices).to_string(),
            "umc1bds32@1,uio1led@lss,jmc@lss/31"
        );
        for (text, problem) in [
            ("jmc@lss7", "PRODUCT@lss or PRODUCT@lss/SERIAL"),
            ("jmc@lss/x", "serial number 'x' is not a 32-bit number"),
            ("jmc@lss/4,jmc@lss/4", "serial number 4 is given twice"),
        ] {
            let err = parse_devices(text).unwrap_err();
            assert!(err.contains(problem), "{text}: {err}");
        }
        // Two of the same product without serials are two devices.
        assert_eq!(parse_devices("jmc@lss,jmc@lss").unwrap().len(), 2);
    }

    #[test]
    fn device_lists_as_the_api_writes_them() {
        assert_eq!(
            parse_devices("demo"),
            Ok(vec![
                spec(Product::Umc1bds32, 1),
                spec(Product::Jmc, 2),
                spec(Product::Uio1led, 3)
            ])
        );
        assert_eq!(parse_devices("none"), Ok(vec![]));
        assert_eq!(parse_devices("empty"), Ok(vec![]));
        assert_eq!(
            parse_devices("umc1bd90@10, UIO1LED@0x7F"),
            Ok(vec![
                spec(Product::Umc1bd90, 10),
                spec(Product::Uio1led, 127)
            ])
        );
    }

    #[test]
    fn a_umc_takes_its_load_as_options_and_bad_ones_are_refused() {
        let devices =
            parse_devices("umc1bds32@1?inertia=0.002&friction=0.0005,umc1bd90@4?friction=0")
                .unwrap();
        assert_eq!(
            devices[0].load,
            Some(Load {
                inertia: 0.002,
                friction: 0.0005
            })
        );
        assert_eq!(
            devices[1].load,
            Some(Load {
                inertia: Load::DEFAULT.inertia,
                friction: 0.0
            })
        );
        assert_eq!(
            DeviceList(devices.clone()).to_string(),
            "umc1bds32@1?inertia=0.002&friction=0.0005,umc1bd90@4?inertia=0.0003&friction=0"
        );
        assert_eq!(
            parse_devices(&DeviceList(devices.clone()).to_string()).unwrap(),
            devices
        );
        for (text, problem) in [
            (
                "jmc@2?inertia=0.001",
                "'jmc@2?inertia=0.001': jmc drives no motor: inertia and friction are options of umc1bds32 and umc1bd90",
            ),
            (
                "umc1bds32@1?inertia=5",
                "'umc1bds32@1?inertia=5': inertia 5 kg·m² is out of range: 0.00002 to 1 (default 0.0003)",
            ),
            (
                "umc1bds32@1?friction=-1",
                "friction -1 N·m·s is out of range: 0 to 0.1",
            ),
            (
                "umc1bds32@1?inertia=heavy",
                "inertia 'heavy' is not a number",
            ),
            ("umc1bds32@1?mass=2", "unknown option 'mass'"),
            ("umc1bds32@1?inertia", "option 'inertia' is not KEY=VALUE"),
            (
                "umc1bds32@1?inertia=0.1&inertia=0.2",
                "inertia is given twice",
            ),
        ] {
            let err = parse_devices(text).unwrap_err();
            assert!(err.contains(problem), "{text}: {err}");
        }
    }

    #[test]
    fn bad_device_lists_say_what_is_wrong() {
        let cases = [
            (
                "jmc",
                "'jmc' is not PRODUCT@NODE (for example jmc@2, or jmc@lss for an unconfigured LSS device); products: umc1bds32, umc1bd90, jmc, uio1led, io401",
            ),
            (
                "servo@2",
                "unknown product 'servo'; products: umc1bds32, umc1bd90, jmc, uio1led, io401",
            ),
            ("jmc@0", "'jmc@0': node id 0 is not 1 to 127"),
            (
                "jmc@2,uio1led@2",
                "node 2 is given twice (jmc@2 and uio1led@2)",
            ),
        ];
        for (text, expected) in cases {
            assert_eq!(parse_devices(text), Err(expected.to_string()), "{text}");
        }
    }
}
