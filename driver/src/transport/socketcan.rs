//! SocketCAN (Linux) through the `socketcan` crate: real adapters (`can0`) and `vcan`.
//!
//! Frames are read and written as the kernel's `struct can_frame` bytes through
//! [`kernel`], the parser the virtual bus shares. The socket is non-blocking;
//! [`CanTransport::recv_deadline`] waits in `poll(2)`. Error frames are enabled
//! (`CAN_RAW_ERR_FILTER` = all classes), so bus-off, error-passive, overflows and controller
//! restarts come back as [`TransportError::Bus`] events instead of silence.

use super::{kernel, BusEvent, CanTransport, Frame, IfName, TransportError};
use ::socketcan::{CanFrame, CanSocket, EmbeddedFrame, Socket, SocketOptions};
use ::socketcan::{ExtendedId, Id, StandardId};
use std::io;
use std::os::fd::AsRawFd;
use std::time::Instant;

/// A raw CAN socket bound to one interface.
pub struct SocketCanTransport {
    sock: CanSocket,
    iface: String,
}

impl SocketCanTransport {
    /// Opens `iface` (e.g. `can0`, `vcan0`), non-blocking, with error frames enabled.
    ///
    /// Fails with the OS error if the interface does not exist or is down; the message names
    /// the interface.
    pub fn open(iface: &str) -> io::Result<Self> {
        let sock = CanSocket::open(iface).map_err(|e| {
            io::Error::new(e.kind(), format!("cannot open CAN interface {iface}: {e}; check `ip link show {iface}` (adapter plugged in? interface up at the configured bitrate?)"))
        })?;
        sock.set_error_filter_accept_all()?;
        sock.set_nonblocking(true)?;
        Ok(SocketCanTransport { sock, iface: iface.to_string() })
    }

    /// The interface name.
    pub fn iface(&self) -> &str {
        &self.iface
    }

    /// The underlying socket, e.g. to set acceptance filters.
    pub fn socket(&self) -> &CanSocket {
        &self.sock
    }

    fn read_one(&mut self) -> Result<Option<Frame>, TransportError> {
        // Read `struct can_frame` as bytes and decode it with the one parser the virtual bus
        // uses too (kernel.rs), so error frames injected in tests take the path real ones take.
        let mut b = [0u8; kernel::CAN_MTU];
        // SAFETY: reads at most b.len() bytes into a buffer we own, on an fd we own.
        let r = unsafe { libc::read(self.sock.as_raw_fd(), b.as_mut_ptr().cast(), b.len()) };
        if r < 0 {
            let e = io::Error::last_os_error();
            return match e.kind() {
                io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted => Ok(None),
                k => Err(TransportError::Io(k)),
            };
        }
        kernel::decode(&b[..r as usize]).map(Some)
    }
}

/// Converts a received SocketCAN frame; error frames become [`TransportError::Bus`].
pub fn from_socketcan(f: &CanFrame) -> Result<Frame, TransportError> {
    let mut data = [0u8; 8];
    match f {
        CanFrame::Error(e) => {
            let d = e.data();
            data[..d.len().min(8)].copy_from_slice(&d[..d.len().min(8)]);
            Err(TransportError::Bus(BusEvent::from_error_frame(e.error_bits(), &data)))
        }
        CanFrame::Remote(_) => Ok(Frame { id: raw_id(f.id()), extended: f.is_extended(), rtr: true, dlc: f.dlc().min(8) as u8, data }),
        CanFrame::Data(_) => {
            let d = f.data();
            let n = d.len().min(8);
            data[..n].copy_from_slice(&d[..n]);
            Ok(Frame { id: raw_id(f.id()), extended: f.is_extended(), rtr: false, dlc: n as u8, data })
        }
    }
}

fn raw_id(id: Id) -> u32 {
    match id {
        Id::Standard(s) => u32::from(s.as_raw()),
        Id::Extended(e) => e.as_raw(),
    }
}

/// Converts a frame for sending; `None` if the id does not fit its format.
pub fn to_socketcan(f: &Frame) -> Option<CanFrame> {
    let id: Id = if f.extended { Id::Extended(ExtendedId::new(f.id)?) } else { Id::Standard(StandardId::new(u16::try_from(f.id).ok()?)?) };
    if f.rtr {
        CanFrame::new_remote(id, usize::from(f.dlc.min(8)))
    } else {
        CanFrame::new(id, f.data())
    }
}

impl CanTransport for SocketCanTransport {
    fn send(&mut self, frame: &Frame) -> Result<(), TransportError> {
        let b = kernel::encode(frame);
        // SAFETY: writes b.len() bytes from a buffer we own to an fd we own.
        let r = unsafe { libc::write(self.sock.as_raw_fd(), b.as_ptr().cast(), b.len()) };
        if r == b.len() as isize {
            return Ok(());
        }
        let e = io::Error::last_os_error();
        match e.kind() {
            // ENOBUFS: the interface's TX queue is full (bus-off or a saturated bus).
            _ if r >= 0 => Err(TransportError::Io(io::ErrorKind::WriteZero)),
            io::ErrorKind::WouldBlock => Err(TransportError::Full(*frame)),
            _ if e.raw_os_error() == Some(libc::ENOBUFS) => Err(TransportError::Full(*frame)),
            k => Err(TransportError::Io(k)),
        }
    }

    fn try_recv(&mut self) -> Result<Option<Frame>, TransportError> {
        self.read_one()
    }

    fn recv_deadline(&mut self, deadline: Instant) -> Result<Option<Frame>, TransportError> {
        loop {
            if let Some(f) = self.read_one()? {
                return Ok(Some(f));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            let wait = deadline - now;
            // Round up so a sub-millisecond wait does not spin.
            let ms = (wait.as_micros().div_ceil(1000)).min(i32::MAX as u128) as i32;
            let mut pfd = libc::pollfd { fd: self.sock.as_raw_fd(), events: libc::POLLIN, revents: 0 };
            // SAFETY: one valid pollfd for the duration of the call.
            let r = unsafe { libc::poll(&mut pfd, 1, ms) };
            if r < 0 {
                let e = io::Error::last_os_error();
                if e.kind() != io::ErrorKind::Interrupted {
                    return Err(TransportError::Io(e.kind()));
                }
            }
        }
    }

    fn iface(&self) -> IfName {
        IfName::new(&self.iface)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_convert_both_ways() {
        for f in [
            Frame::new(0x123, &[1, 2, 3]),
            Frame::try_new(0x1ABC_DEF0, true, &[9; 8]).unwrap(),
            Frame::remote(0x321, false, 4).unwrap(),
            Frame::new(0, &[]),
        ] {
            let s = to_socketcan(&f).unwrap();
            assert_eq!(from_socketcan(&s).unwrap(), f);
        }
        let e = ::socketcan::CanErrorFrame::new_error(0x040, &[]).unwrap();
        assert_eq!(from_socketcan(&CanFrame::Error(e)), Err(TransportError::Bus(BusEvent::BusOff)));
    }

    #[test]
    fn opening_a_missing_interface_names_it() {
        let err = SocketCanTransport::open("nosuchcan9").err().expect("must fail");
        assert!(err.to_string().contains("nosuchcan9"), "{err}");
    }
}
