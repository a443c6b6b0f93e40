use super::*;
use crate::canopen::eds::Eds;

#[test]
fn channel_names_read_both_ways_and_bad_ones_are_refused() {
    for (name, kind, number) in [
        ("di1", ChannelKind::DigitalInput, 1),
        ("do16", ChannelKind::DigitalOutput, 16),
        ("ai4", ChannelKind::AnalogInput, 4),
        ("ao2", ChannelKind::AnalogOutput, 2),
    ] {
        let channel = Channel::parse(name).unwrap();
        assert_eq!((channel.kind, channel.number), (kind, number), "{name}");
        assert_eq!(channel.to_string(), name, "{name}");
    }
    for bad in ["", "di", "di0", "dx1", "ai-1", "do1a", "d", "ao99999"] {
        assert_eq!(Channel::parse(bad), None, "{bad}");
        assert_eq!(Channel::read_loosely(bad), None, "{bad}");
    }
    // One spelling: other spellings are refused, and read loosely only to
    // name the accepted form.
    for (other, meant) in [
        ("DO1", "do1"),
        ("do01", "do1"),
        ("do1 ", "do1"),
        (" Ai12", "ai12"),
    ] {
        assert_eq!(Channel::parse(other), None, "{other}");
        let loose = Channel::read_loosely(other).unwrap();
        assert_eq!(loose.to_string(), meant, "{other}");
    }
}

#[test]
fn digital_channels_are_bits_of_8_bit_groups_and_analogue_ones_sub_indices() {
    let at = |name: &str| Channel::parse(name).unwrap().location();
    assert_eq!(at("di1"), (0x6000, 1, Some(0)));
    assert_eq!(at("di8"), (0x6000, 1, Some(7)));
    assert_eq!(at("di9"), (0x6000, 2, Some(0)));
    assert_eq!(at("do16"), (0x6200, 2, Some(7)));
    assert_eq!(at("ai3"), (0x6401, 3, None));
    assert_eq!(at("ao2"), (0x6411, 2, None));
    assert!(bit(0b0000_0100, 2));
    assert!(!bit(0b0000_0100, 1));
    assert_eq!(with_bit(0b1010, 0, true), 0b1011);
    assert_eq!(with_bit(0b1010, 3, false), 0b0010);
}

#[test]
fn the_io401_eds_has_16_digital_in_16_out_4_analogue_in_2_out() {
    let eds = Eds::parse(crate::builtin::IO401, "io401.eds").unwrap();
    assert!(eds.warnings.is_empty(), "{:?}", eds.warnings);
    let layout = Layout::from_dictionary(&eds.dictionary);
    assert_eq!(
        layout,
        Layout {
            digital_inputs: 16,
            digital_outputs: 16,
            analog_inputs: 4,
            analog_outputs: 2,
        }
    );
    assert!(layout.contains(Channel::parse("do16").unwrap()));
    assert!(!layout.contains(Channel::parse("do17").unwrap()));
    assert!(!layout.contains(Channel::parse("ao3").unwrap()));
    assert_eq!(Layout::from_highest_subs(2, 2, 4, 2), layout);
    assert_eq!(
        layout
            .channels(ChannelKind::AnalogOutput)
            .map(|c| c.to_string())
            .collect::<Vec<_>>(),
        ["ao1", "ao2"]
    );
    // The profile objects are there, by their CiA 401 names.
    for (index, name) in [
        (POLARITY_INPUT_8, "Polarity input 8-bit"),
        (FILTER_CONSTANT_INPUT_8, "Filter constant input 8-bit"),
        (
            GLOBAL_INTERRUPT_ENABLE_DIGITAL,
            "Global interrupt enable digital",
        ),
        (
            INTERRUPT_MASK_ANY_CHANGE_8,
            "Interrupt mask any change 8-bit",
        ),
        (
            INTERRUPT_MASK_LOW_TO_HIGH_8,
            "Interrupt mask low-to-high 8-bit",
        ),
        (
            INTERRUPT_MASK_HIGH_TO_LOW_8,
            "Interrupt mask high-to-low 8-bit",
        ),
        (CHANGE_POLARITY_OUTPUT_8, "Change polarity output 8-bit"),
        (ERROR_MODE_OUTPUT_8, "Error mode output 8-bit"),
        (ERROR_VALUE_OUTPUT_8, "Error value output 8-bit"),
        (FILTER_MASK_OUTPUT_8, "Filter mask output 8-bit"),
        (
            ANALOG_INPUT_TRIGGER_SELECTION,
            "Analog input interrupt trigger selection",
        ),
        (
            ANALOG_INPUT_GLOBAL_INTERRUPT_ENABLE,
            "Analog input global interrupt enable",
        ),
        (
            ANALOG_INPUT_INTERRUPT_DELTA,
            "Analog input interrupt delta unsigned",
        ),
        (ANALOG_OUTPUT_ERROR_MODE, "Analog output error mode"),
        (
            ANALOG_OUTPUT_ERROR_VALUE,
            "Analog output error value integer",
        ),
    ] {
        assert_eq!(eds.dictionary.get(index).unwrap().name, name);
    }
}

#[test]
fn a_channels_level_is_its_bit_of_the_group_or_its_integer16() {
    let di10 = Channel::parse("di10").unwrap();
    // di10 is bit 1 of sub 2: the other bits of the group do not matter.
    assert_eq!(di10.level_in(&[0b0000_0010]), Some(Level::Digital(true)));
    assert_eq!(di10.level_in(&[0b1111_1101]), Some(Level::Digital(false)));
    let ai2 = Channel::parse("ai2").unwrap();
    assert_eq!(ai2.level_in(&[0x18, 0xFC]), Some(Level::Analog(-1000)));
    // Too few bytes for the object: no value.
    assert_eq!(di10.level_in(&[]), None);
    assert_eq!(ai2.level_in(&[0x18]), None);
}
