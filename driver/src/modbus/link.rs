//! The Modbus master's link on a real serial port (`serialport` 4, a tty or a pseudo-terminal):
//! [`SerialPortLink`], an implementation of `taut_proto::modbus::link::SerialLink`.

use std::io::{Read, Write};
use std::time::Duration;
use taut_proto::devices::{LoadCellBusConfig, Parity};
use taut_proto::modbus::link::{LinkError, SerialLink};

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
