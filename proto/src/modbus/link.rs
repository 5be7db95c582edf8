//! The byte link a Modbus RTU master and a device talk through: a tiny trait and its error.
//! Implementations open the ports (`taut_driver::modbus::link::SerialPortLink` on a tty); tests
//! add scripted links.
//!
//! Kept apart from the codec so the RTU core never sees a file descriptor.

use std::time::Duration;

/// Why the link failed. `Copy`; any of these ends the connection: the master drops the port and
/// reopens it with back-off.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkError {
    /// The device node does not exist (adapter unplugged, udev rule not installed).
    NotFound,
    /// No permission to open the device (user not in the `taut` group?).
    PermissionDenied,
    /// Another process holds the port.
    Busy,
    /// The port was open and failed: hang-up or I/O error, as when a USB adapter goes away.
    Gone(std::io::ErrorKind),
    /// The port refused the configured settings.
    Settings,
}

impl std::fmt::Display for LinkError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LinkError::NotFound => write!(f, "serial device not found (adapter unplugged or udev rule missing?)"),
            LinkError::PermissionDenied => write!(f, "permission denied (is the user in the `taut` group?)"),
            LinkError::Busy => write!(f, "serial device busy (another process has it open)"),
            LinkError::Gone(k) => write!(f, "serial port failed ({k}): adapter gone?"),
            LinkError::Settings => write!(f, "serial port refused the configured settings"),
        }
    }
}

/// A half-duplex byte link.
pub trait SerialLink {
    /// Sends a whole frame.
    fn send(&mut self, frame: &[u8]) -> Result<(), LinkError>;
    /// Receives what is there, waiting at most `timeout` for the first byte; `Ok(0)` when
    /// nothing came in time. A zero `timeout` takes what has already arrived without waiting.
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError>;
    /// Drops bytes received but not read (a late answer to an earlier request).
    fn discard_input(&mut self) -> Result<(), LinkError>;
}

impl<L: SerialLink + ?Sized> SerialLink for &mut L {
    fn send(&mut self, frame: &[u8]) -> Result<(), LinkError> {
        (**self).send(frame)
    }
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        (**self).recv(buf, timeout)
    }
    fn discard_input(&mut self) -> Result<(), LinkError> {
        (**self).discard_input()
    }
}
