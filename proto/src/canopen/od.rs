//! Object dictionary indices used by the master and the virtual drives.
//!
//! ```text
//! index   sub   type  access  meaning                                      unit
//! 0x1000  0     u32   ro      device type (0x00020192: CiA 402 servo)
//! 0x1008  0     str   ro      manufacturer device name
//! 0x1016  1     u32   rw      consumer heartbeat: node id << 16 | time   ms
//! 0x1017  0     u16   rw      producer heartbeat time                     ms
//! 0x1018  1..4  u32   ro      identity: vendor, product, revision, serial
//! 0x1400+ 1..2  u32/u8 rw     RPDO communication: COB-ID, transmission type
//! 0x1600+ 0..8  u32   rw      RPDO mapping: count, entries (index<<16 | sub<<8 | bits)
//! 0x1800+ 1..2  u32/u8 rw     TPDO communication: COB-ID, transmission type
//! 0x1A00+ 0..8  u32   rw      TPDO mapping
//! 0x6007  0     i16   rw      abort connection option code (0..3)
//! 0x603F  0     u16   ro      error code (last fault)
//! 0x6040  0     u16   rw      controlword
//! 0x6041  0     u16   ro      statusword
//! 0x6060  0     i8    rw      modes of operation (8 CSP, 10 CST)
//! 0x6061  0     i8    ro      modes of operation display
//! 0x6064  0     i32   ro      position actual value                       counts
//! 0x606C  0     i32   ro      velocity actual value                       counts/s
//! 0x6071  0     i16   rw      target torque                               ‰ of rated torque
//! 0x6077  0     i16   ro      torque actual value                         ‰ of rated torque
//! 0x607A  0     i32   rw      target position                             counts
//! ```

/// Device type.
pub const DEVICE_TYPE: u16 = 0x1000;
/// Manufacturer device name (visible string; read with a segmented upload).
pub const DEVICE_NAME: u16 = 0x1008;
/// Consumer heartbeat time (sub 1..: node id << 16 | time in ms).
pub const HEARTBEAT_CONSUMER: u16 = 0x1016;
/// Producer heartbeat time, ms.
pub const HEARTBEAT_PRODUCER: u16 = 0x1017;
/// Identity object.
pub const IDENTITY: u16 = 0x1018;
/// First RPDO communication parameter.
pub const RPDO_COMM: u16 = 0x1400;
/// First RPDO mapping parameter.
pub const RPDO_MAP: u16 = 0x1600;
/// First TPDO communication parameter.
pub const TPDO_COMM: u16 = 0x1800;
/// First TPDO mapping parameter.
pub const TPDO_MAP: u16 = 0x1A00;
/// Abort connection option code (CiA 402): 0 none, 1 fault, 2 disable voltage, 3 quick stop.
pub const ABORT_CONNECTION: u16 = 0x6007;
/// Error code (CiA 402).
pub const ERROR_CODE: u16 = 0x603F;
/// Controlword.
pub const CONTROLWORD: u16 = 0x6040;
/// Statusword.
pub const STATUSWORD: u16 = 0x6041;
/// Modes of operation.
pub const MODES_OF_OPERATION: u16 = 0x6060;
/// Modes of operation display.
pub const MODES_OF_OPERATION_DISPLAY: u16 = 0x6061;
/// Position actual value, counts.
pub const POSITION_ACTUAL: u16 = 0x6064;
/// Velocity actual value, counts/s.
pub const VELOCITY_ACTUAL: u16 = 0x606C;
/// Target torque, per mille of rated torque.
pub const TARGET_TORQUE: u16 = 0x6071;
/// Torque actual value, per mille of rated torque.
pub const TORQUE_ACTUAL: u16 = 0x6077;
/// Target position, counts.
pub const TARGET_POSITION: u16 = 0x607A;
/// Device type of a CiA 402 servo drive: profile 402 (low word), additional info 0x0002 servo.
pub const DEVICE_TYPE_CIA402_SERVO: u32 = 0x0002_0192;
