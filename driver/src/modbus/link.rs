//! The byte link the Modbus master talks through: a tiny trait, and its implementation on a real
//! serial port (`serialport` 4, a tty or a pseudo-terminal). Tests add scripted links.
//!
//! Kept apart from the codec so the RTU core never sees a file descriptor.

use std::io::{Read, Write};
use std::time::Duration;
use taut_config::devices::{LoadCellBusConfig, Parity};

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

/// A real serial port.
pub struct SerialPortLink {
    port: serialport::TTYPort,
    timeout: Duration,
}

fn map_io(e: &std::io::Error) -> LinkError {
    LinkError::Gone(e.kind())
}

fn map_open(e: serialport::Error) -> LinkError {
    use serialport::ErrorKind as K;
    match e.kind {
        K::NoDevice => LinkError::Busy,
        K::Io(std::io::ErrorKind::NotFound) => LinkError::NotFound,
        K::Io(std::io::ErrorKind::PermissionDenied) => LinkError::PermissionDenied,
        K::Io(k) => LinkError::Gone(k),
        K::InvalidInput | K::Unknown => LinkError::Settings,
    }
}

impl SerialPortLink {
    /// Opens the configured port (exclusive, raw, no flow control).
    pub fn open(cfg: &LoadCellBusConfig) -> Result<SerialPortLink, LinkError> {
        // Checked up front: serialport reports a missing node as a generic I/O error on some
        // paths, and "not found" is the one people need to see on an unplugged adapter.
        if !std::path::Path::new(&cfg.port).exists() {
            return Err(LinkError::NotFound);
        }
        let parity = match cfg.parity {
            Parity::None => serialport::Parity::None,
            Parity::Even => serialport::Parity::Even,
            Parity::Odd => serialport::Parity::Odd,
        };
        let stop = if cfg.stop_bits == 2 { serialport::StopBits::Two } else { serialport::StopBits::One };
        let timeout = Duration::from_millis(10);
        let port = serialport::new(cfg.port.as_str(), cfg.baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(parity)
            .stop_bits(stop)
            .flow_control(serialport::FlowControl::None)
            .timeout(timeout)
            .open_native()
            .map_err(map_open)?;
        let mut link = SerialPortLink { port, timeout };
        link.discard_input()?;
        Ok(link)
    }

    /// Wraps an already open port (one end of `TTYPort::pair()` in tests).
    pub fn from_port(port: serialport::TTYPort) -> SerialPortLink {
        use serialport::SerialPort;
        SerialPortLink { timeout: port.timeout(), port }
    }
}

impl SerialLink for SerialPortLink {
    fn send(&mut self, frame: &[u8]) -> Result<(), LinkError> {
        self.port.write_all(frame).map_err(|e| map_io(&e))
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        use serialport::SerialPort;
        if buf.is_empty() {
            return Ok(0);
        }
        if timeout != self.timeout {
            // Only stores the value: serialport polls with it on each read.
            self.port.set_timeout(timeout).map_err(|_| LinkError::Settings)?;
            self.timeout = timeout;
        }
        loop {
            match self.port.read(buf) {
                // A tty read of 0 bytes after poll said readable is a hang-up.
                Ok(0) => return Err(LinkError::Gone(std::io::ErrorKind::UnexpectedEof)),
                Ok(n) => return Ok(n),
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => return Ok(0),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(map_io(&e)),
            }
        }
    }

    fn discard_input(&mut self) -> Result<(), LinkError> {
        use serialport::SerialPort;
        self.port.clear(serialport::ClearBuffer::Input).map_err(|e| match e.kind {
            serialport::ErrorKind::Io(k) => LinkError::Gone(k),
            _ => LinkError::Gone(std::io::ErrorKind::Other),
        })
    }
}
