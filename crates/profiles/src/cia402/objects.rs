//! The CiA 402 objects (CiA 402-2, the drive profile's object dictionary):
//! the one table of their indexes, axis 1's (a drive with more axes has
//! each at an offset: [`crate::umc::axis_index`]). The products'
//! modules say what their devices make of them (types, units, the objects a
//! product uses in place of another).

/// 0x6007, abort connection option code (INTEGER16).
pub const ABORT_CONNECTION_OPTION: u16 = 0x6007;
/// 0x6040, controlword (UNSIGNED16).
pub const CONTROLWORD: u16 = 0x6040;
/// 0x6041, statusword (UNSIGNED16).
pub const STATUSWORD: u16 = 0x6041;
/// 0x6042, vl target velocity (INTEGER16).
pub const VL_TARGET: u16 = 0x6042;
/// 0x6043, vl velocity demand (INTEGER16).
pub const VL_DEMAND: u16 = 0x6043;
/// 0x6044, vl velocity actual value (INTEGER16).
pub const VL_ACTUAL: u16 = 0x6044;
/// 0x6046, vl velocity min max amount (UNSIGNED32; sub 1 min, 2 max).
pub const VL_MIN_MAX: u16 = 0x6046;
/// 0x6048, vl velocity acceleration (sub 1 delta speed, sub 2 delta time).
pub const VL_ACCELERATION: u16 = 0x6048;
/// 0x6049, vl velocity deceleration (as 0x6048).
pub const VL_DECELERATION: u16 = 0x6049;
/// 0x604A, vl velocity quick stop (as 0x6048).
pub const VL_QUICK_STOP: u16 = 0x604A;
/// 0x604B, vl set-point factor (INTEGER16; sub 1 numerator, 2 denominator).
pub const VL_SET_POINT_FACTOR: u16 = 0x604B;
/// 0x604C, vl dimension factor (INTEGER32; sub 1 numerator, 2 denominator).
pub const VL_DIMENSION_FACTOR: u16 = 0x604C;
/// 0x605A, quick stop option code (INTEGER16).
pub const QUICK_STOP_OPTION: u16 = 0x605A;
/// 0x605B, shutdown option code (INTEGER16).
pub const SHUTDOWN_OPTION: u16 = 0x605B;
/// 0x605C, disable operation option code (INTEGER16).
pub const DISABLE_OPERATION_OPTION: u16 = 0x605C;
/// 0x605D, halt option code (INTEGER16).
pub const HALT_OPTION: u16 = 0x605D;
/// 0x605E, fault reaction option code (INTEGER16).
pub const FAULT_REACTION_OPTION: u16 = 0x605E;
/// 0x6060, modes of operation (INTEGER8), see [`super::Mode`].
pub const MODES_OF_OPERATION: u16 = 0x6060;
/// 0x6061, modes of operation display (INTEGER8).
pub const MODES_OF_OPERATION_DISPLAY: u16 = 0x6061;
/// 0x6062, position demand value (INTEGER32).
pub const POSITION_DEMAND: u16 = 0x6062;
/// 0x6063, position actual internal value (INTEGER32).
pub const POSITION_ACTUAL_INTERNAL: u16 = 0x6063;
/// 0x6064, position actual value (INTEGER32).
pub const POSITION_ACTUAL: u16 = 0x6064;
/// 0x6065, following error window (UNSIGNED32).
pub const FOLLOWING_ERROR_WINDOW: u16 = 0x6065;
/// 0x6066, following error time out (UNSIGNED16, ms).
pub const FOLLOWING_ERROR_TIME_OUT: u16 = 0x6066;
/// 0x6067, position window (UNSIGNED32).
pub const POSITION_WINDOW: u16 = 0x6067;
/// 0x6068, position window time (UNSIGNED16, ms).
pub const POSITION_WINDOW_TIME: u16 = 0x6068;
/// 0x606B, velocity demand value (INTEGER32).
pub const VELOCITY_DEMAND: u16 = 0x606B;
/// 0x606C, velocity actual value (INTEGER32).
pub const VELOCITY_ACTUAL: u16 = 0x606C;
/// 0x6071, target torque (INTEGER16, per mille of the rated torque).
pub const TQ_TARGET: u16 = 0x6071;
/// 0x6072, max torque (UNSIGNED16).
pub const TQ_MAX: u16 = 0x6072;
/// 0x6073, max current (UNSIGNED16).
pub const MAX_CURRENT: u16 = 0x6073;
/// 0x6074, torque demand (INTEGER16).
pub const TQ_DEMAND: u16 = 0x6074;
/// 0x6075, motor rated current (UNSIGNED32).
pub const RATED_CURRENT: u16 = 0x6075;
/// 0x6077, torque actual value (INTEGER16).
pub const TQ_ACTUAL: u16 = 0x6077;
/// 0x6078, current actual value (INTEGER16).
pub const CURRENT_ACTUAL: u16 = 0x6078;
/// 0x6079, DC link circuit voltage (UNSIGNED32).
pub const DC_LINK_VOLTAGE: u16 = 0x6079;
/// 0x607A, target position (INTEGER32).
pub const TARGET_POSITION: u16 = 0x607A;
/// 0x607C, home offset (INTEGER32).
pub const HOME_OFFSET: u16 = 0x607C;
/// 0x607D, software position limit (INTEGER32; sub 1 min, 2 max).
pub const SOFTWARE_POSITION_LIMIT: u16 = 0x607D;
/// 0x607F, max profile velocity (UNSIGNED32).
pub const MAX_PROFILE_VELOCITY: u16 = 0x607F;
/// 0x6080, max motor speed (UNSIGNED32).
pub const MAX_MOTOR_SPEED: u16 = 0x6080;
/// 0x6081, profile velocity (UNSIGNED32).
pub const PROFILE_VELOCITY: u16 = 0x6081;
/// 0x6083, profile acceleration (UNSIGNED32).
pub const PROFILE_ACCELERATION: u16 = 0x6083;
/// 0x6084, profile deceleration (UNSIGNED32).
pub const PROFILE_DECELERATION: u16 = 0x6084;
/// 0x6085, quick stop deceleration (UNSIGNED32).
pub const QUICK_STOP_DECELERATION: u16 = 0x6085;
/// 0x6087, torque slope (UNSIGNED32).
pub const TQ_SLOPE: u16 = 0x6087;
/// 0x608F, position encoder resolution (UNSIGNED32; sub 1 encoder
/// increments, sub 2 motor revolutions).
pub const POSITION_ENCODER_RESOLUTION: u16 = 0x608F;
/// 0x6091, gear ratio (UNSIGNED32; sub 1 motor revolutions, sub 2 shaft
/// revolutions).
pub const GEAR_RATIO: u16 = 0x6091;
/// 0x6098, homing method (INTEGER8).
pub const HOMING_METHOD: u16 = 0x6098;
/// 0x6099, homing speeds (UNSIGNED32; sub 1 search for switch, 2 search for zero).
pub const HOMING_SPEEDS: u16 = 0x6099;
/// 0x609A, homing acceleration (UNSIGNED32).
pub const HOMING_ACCELERATION: u16 = 0x609A;
/// 0x60C1, interpolation data record (sub 1: a set-point).
pub const IP_DATA_RECORD: u16 = 0x60C1;
/// 0x60C2, interpolation time period (sub 1 units, sub 2 index: units × 10^index s).
pub const IP_TIME_PERIOD: u16 = 0x60C2;
/// 0x60C4, interpolation data configuration (sub 1 maximum, 2 actual buffer size, 6 buffer clear).
pub const IP_DATA_CONFIGURATION: u16 = 0x60C4;
/// 0x60C5, max acceleration (UNSIGNED32).
pub const MAX_ACCELERATION: u16 = 0x60C5;
/// 0x60C6, max deceleration (UNSIGNED32).
pub const MAX_DECELERATION: u16 = 0x60C6;
/// 0x60F4, following error actual value (INTEGER32).
pub const FOLLOWING_ERROR_ACTUAL: u16 = 0x60F4;
/// 0x60FA, control effort (INTEGER32).
pub const CONTROL_EFFORT: u16 = 0x60FA;
/// 0x60FF, target velocity of profile velocity mode (INTEGER32).
pub const TARGET_VELOCITY: u16 = 0x60FF;
/// 0x6502, supported drive modes (UNSIGNED32), see [`super::Mode::supported`].
pub const SUPPORTED_DRIVE_MODES: u16 = 0x6502;
