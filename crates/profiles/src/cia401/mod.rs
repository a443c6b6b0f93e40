//! CiA 401, the device profile of generic I/O modules: what its objects
//! mean to the gateway (the I/O view, `GET/PUT .../io`) and to the virtual
//! `io401`.
//!
//! The names are CiA 401's, as public EDS files of I/O modules give them
//! (SYSTEC's IoX1, CANFestival's DS401 slave):
//!
//! | index | object | type |
//! |---|---|---|
//! | 0x6000 | Read input 8-bit (digital inputs, 8 per sub-index) | UNSIGNED8 |
//! | 0x6002 | Polarity input 8-bit (a set bit inverts the input) | UNSIGNED8 |
//! | 0x6003 | Filter constant input 8-bit | UNSIGNED8 |
//! | 0x6005 | Global interrupt enable digital | BOOLEAN |
//! | 0x6006 / 0x6007 / 0x6008 | Interrupt mask any change / low-to-high / high-to-low 8-bit | UNSIGNED8 |
//! | 0x6200 | Write output 8-bit (digital outputs, 8 per sub-index) | UNSIGNED8 |
//! | 0x6202 | Change polarity output 8-bit | UNSIGNED8 |
//! | 0x6206 / 0x6207 | Error mode / error value output 8-bit | UNSIGNED8 |
//! | 0x6208 | Filter mask output 8-bit | UNSIGNED8 |
//! | 0x6401 | Read analog input 16-bit | INTEGER16 |
//! | 0x6411 | Write analog output 16-bit | INTEGER16 |
//! | 0x6421 | Analog input interrupt trigger selection | UNSIGNED8 |
//! | 0x6423 | Analog input global interrupt enable | BOOLEAN |
//! | 0x6426 | Analog input interrupt delta unsigned | UNSIGNED32 |
//! | 0x6443 / 0x6444 | Analog output error mode / error value integer | UNSIGNED8 / INTEGER32 |
//!
//! Channels are numbered from 1 per kind and named `di1`, `do1`, `ai1`,
//! `ao1`: digital channel `n` is bit `(n − 1) mod 8` of sub-index
//! `(n − 1) / 8 + 1` (channel 1 is bit 0 of sub 1), analogue channel `n` is
//! sub-index `n`.

use std::fmt;

use crate::canopen::od::ObjectDictionary;

#[cfg(test)]
mod tests;

/// 0x6000 Read input 8-bit.
pub const READ_INPUT_8: u16 = 0x6000;
/// 0x6002 Polarity input 8-bit.
pub const POLARITY_INPUT_8: u16 = 0x6002;
/// 0x6003 Filter constant input 8-bit.
pub const FILTER_CONSTANT_INPUT_8: u16 = 0x6003;
/// 0x6005 Global interrupt enable digital.
pub const GLOBAL_INTERRUPT_ENABLE_DIGITAL: u16 = 0x6005;
/// 0x6006 Interrupt mask any change 8-bit.
pub const INTERRUPT_MASK_ANY_CHANGE_8: u16 = 0x6006;
/// 0x6007 Interrupt mask low-to-high 8-bit.
pub const INTERRUPT_MASK_LOW_TO_HIGH_8: u16 = 0x6007;
/// 0x6008 Interrupt mask high-to-low 8-bit.
pub const INTERRUPT_MASK_HIGH_TO_LOW_8: u16 = 0x6008;
/// 0x6200 Write output 8-bit.
pub const WRITE_OUTPUT_8: u16 = 0x6200;
/// 0x6202 Change polarity output 8-bit.
pub const CHANGE_POLARITY_OUTPUT_8: u16 = 0x6202;
/// 0x6206 Error mode output 8-bit.
pub const ERROR_MODE_OUTPUT_8: u16 = 0x6206;
/// 0x6207 Error value output 8-bit.
pub const ERROR_VALUE_OUTPUT_8: u16 = 0x6207;
/// 0x6208 Filter mask output 8-bit.
pub const FILTER_MASK_OUTPUT_8: u16 = 0x6208;
/// 0x6401 Read analog input 16-bit.
pub const READ_ANALOG_INPUT_16: u16 = 0x6401;
/// 0x6411 Write analog output 16-bit.
pub const WRITE_ANALOG_OUTPUT_16: u16 = 0x6411;
/// 0x6421 Analog input interrupt trigger selection.
pub const ANALOG_INPUT_TRIGGER_SELECTION: u16 = 0x6421;
/// 0x6423 Analog input global interrupt enable.
pub const ANALOG_INPUT_GLOBAL_INTERRUPT_ENABLE: u16 = 0x6423;
/// 0x6426 Analog input interrupt delta unsigned.
pub const ANALOG_INPUT_INTERRUPT_DELTA: u16 = 0x6426;
/// 0x6443 Analog output error mode.
pub const ANALOG_OUTPUT_ERROR_MODE: u16 = 0x6443;
/// 0x6444 Analog output error value integer.
pub const ANALOG_OUTPUT_ERROR_VALUE: u16 = 0x6444;

/// The four kinds of channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ChannelKind {
    /// `di`: 0x6000, bit by bit.
    DigitalInput,
    /// `do`: 0x6200, bit by bit.
    DigitalOutput,
    /// `ai`: 0x6401, INTEGER16 per sub-index.
    AnalogInput,
    /// `ao`: 0x6411, INTEGER16 per sub-index.
    AnalogOutput,
}

impl ChannelKind {
    pub const ALL: [ChannelKind; 4] = [
        Self::DigitalInput,
        Self::DigitalOutput,
        Self::AnalogInput,
        Self::AnalogOutput,
    ];

    /// The prefix of the channels' names.
    pub fn prefix(self) -> &'static str {
        match self {
            Self::DigitalInput => "di",
            Self::DigitalOutput => "do",
            Self::AnalogInput => "ai",
            Self::AnalogOutput => "ao",
        }
    }

    /// The object that holds the channels.
    pub fn index(self) -> u16 {
        match self {
            Self::DigitalInput => READ_INPUT_8,
            Self::DigitalOutput => WRITE_OUTPUT_8,
            Self::AnalogInput => READ_ANALOG_INPUT_16,
            Self::AnalogOutput => WRITE_ANALOG_OUTPUT_16,
        }
    }

    pub fn is_digital(self) -> bool {
        matches!(self, Self::DigitalInput | Self::DigitalOutput)
    }

    pub fn is_output(self) -> bool {
        matches!(self, Self::DigitalOutput | Self::AnalogOutput)
    }
}

/// One channel: its kind and number (from 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Channel {
    pub kind: ChannelKind,
    pub number: u16,
}

impl Channel {
    /// `di3`, `ao1`: a kind's prefix and a number from 1 (the count of the
    /// module is checked by [`Layout::contains`]), in one spelling only:
    /// lowercase, no leading zeros, no spaces (issue 30, finding 8: `DO1`,
    /// `do01` and `"do1 "` are not `do1`; [`Self::read_loosely`] says what
    /// such a name meant, for the error).
    pub fn parse(name: &str) -> Option<Self> {
        Self::read_loosely(name).filter(|channel| channel.to_string() == name)
    }

    /// The channel a name not in the one spelling of [`Self::parse`]
    /// stands for (`DO1`, `do01`, `" do1 "`): for the error that names the
    /// accepted form, never to act on.
    pub fn read_loosely(name: &str) -> Option<Self> {
        let name = name.trim();
        let kind = ChannelKind::ALL.into_iter().find(|kind| {
            name.get(..2)
                .is_some_and(|prefix| prefix.eq_ignore_ascii_case(kind.prefix()))
        })?;
        let digits = &name[2..];
        if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        let number: u16 = digits.parse().ok().filter(|&n| n >= 1)?;
        Some(Self { kind, number })
    }

    /// Where the channel lives: index, sub-index and, for a digital one,
    /// its bit in that sub-index's byte.
    pub fn location(self) -> (u16, u8, Option<u8>) {
        let index = self.kind.index();
        let n = self.number - 1;
        if self.kind.is_digital() {
            (index, (n / 8 + 1) as u8, Some((n % 8) as u8))
        } else {
            (index, self.number as u8, None)
        }
    }

    /// The channel's value in its object's bytes as the device sends them
    /// (little-endian, by SDO or in a TPDO): its bit of the 8-bit group for
    /// a digital channel, the INTEGER16 for an analogue one; `None` when
    /// the bytes are too few.
    pub fn level_in(self, data: &[u8]) -> Option<Level> {
        match (self.location().2, data) {
            (Some(bit), [group, ..]) => Some(Level::Digital(self::bit(*group, bit))),
            (None, [low, high, ..]) => Some(Level::Analog(i16::from_le_bytes([*low, *high]))),
            _ => None,
        }
    }
}

/// A channel's value: a digital channel's state, an analogue one's
/// INTEGER16 (CiA 401 gives it no unit).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    Digital(bool),
    Analog(i16),
}

impl fmt::Display for Channel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}{}", self.kind.prefix(), self.number)
    }
}

/// How many channels of each kind a module has.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Layout {
    pub digital_inputs: u16,
    pub digital_outputs: u16,
    pub analog_inputs: u16,
    pub analog_outputs: u16,
}

impl Layout {
    /// From a dictionary: 8 digital channels per sub-index of 0x6000 and
    /// 0x6200 (sub 1 on, consecutive), one analogue channel per sub-index of
    /// 0x6401 and 0x6411.
    pub fn from_dictionary(dictionary: &ObjectDictionary) -> Self {
        let subs = |index: u16| -> u16 {
            (1..=254u8)
                .take_while(|&sub| dictionary.sub(index, sub).is_some())
                .count() as u16
        };
        Self {
            digital_inputs: subs(READ_INPUT_8) * 8,
            digital_outputs: subs(WRITE_OUTPUT_8) * 8,
            analog_inputs: subs(READ_ANALOG_INPUT_16),
            analog_outputs: subs(WRITE_ANALOG_OUTPUT_16),
        }
    }

    /// From the highest sub-indices of 0x6000, 0x6200, 0x6401 and 0x6411
    /// (sub 0), as read from a device.
    pub fn from_highest_subs(di: u8, dout: u8, ai: u8, ao: u8) -> Self {
        Self {
            digital_inputs: u16::from(di) * 8,
            digital_outputs: u16::from(dout) * 8,
            analog_inputs: u16::from(ai),
            analog_outputs: u16::from(ao),
        }
    }

    pub fn count(&self, kind: ChannelKind) -> u16 {
        match kind {
            ChannelKind::DigitalInput => self.digital_inputs,
            ChannelKind::DigitalOutput => self.digital_outputs,
            ChannelKind::AnalogInput => self.analog_inputs,
            ChannelKind::AnalogOutput => self.analog_outputs,
        }
    }

    pub fn contains(&self, channel: Channel) -> bool {
        channel.number <= self.count(channel.kind)
    }

    /// Every channel of a kind, from 1.
    pub fn channels(&self, kind: ChannelKind) -> impl Iterator<Item = Channel> {
        (1..=self.count(kind)).map(move |number| Channel { kind, number })
    }

    pub fn is_empty(&self) -> bool {
        ChannelKind::ALL.iter().all(|&kind| self.count(kind) == 0)
    }
}

/// Bit `bit` of `byte`.
pub fn bit(byte: u8, bit: u8) -> bool {
    byte & (1 << bit) != 0
}

/// `byte` with bit `bit` set to `on`.
pub fn with_bit(byte: u8, bit: u8, on: bool) -> u8 {
    if on {
        byte | (1 << bit)
    } else {
        byte & !(1 << bit)
    }
}
