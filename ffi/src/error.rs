//! Error codes and the per-thread last error message.
//!
//! The message lives in a fixed buffer in thread-local storage (const-initialised, no
//! destructor): writing it allocates nothing, so `taut_update` can fail with a message on the
//! real-time thread.

use std::cell::RefCell;
use std::fmt::{self, Write};

/// What a call returns. `TAUT_ERROR_OK` (0) is success; any other value is a failure whose
/// message [`taut_last_error`](crate::taut_last_error) gives on the same thread.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TautError {
    /// Success.
    Ok = 0,
    /// A required pointer argument was NULL.
    NullPointer = 1,
    /// An argument or a field of a struct is out of range (the message names it).
    InvalidArgument = 2,
    /// The robot configuration was refused (the message names the file, line and key).
    Config = 3,
    /// The call is not allowed in the plugin's lifecycle state or device mode (e.g. update
    /// before activate).
    WrongState = 4,
    /// Another thread is inside a real-time or lifecycle call on this handle.
    Busy = 5,
    /// The operator request was refused (the message says why and what to do).
    Refused = 6,
    /// A file or thread could not be created (the message names it).
    Io = 7,
    /// Plugin-owned devices could not be brought up, or the drives did not enable (the message
    /// says which and why; the robot is left safe and `taut_activate` may be retried).
    Device = 8,
    /// A panic inside taut was caught at the boundary; the handle is unusable (only
    /// `taut_cleanup` may follow).
    Panic = 9,
    /// Nothing to report (`taut_poll_event` without an event). Not a failure.
    NoEvent = 10,
}

/// Longest message kept, bytes (longer ones are cut at a character boundary).
const CAP: usize = 1024;

struct LastError {
    buf: [u8; CAP],
    len: usize,
}

thread_local! {
    // const-initialised and without a destructor: access never allocates or registers one.
    static LAST: RefCell<LastError> = const { RefCell::new(LastError { buf: [0; CAP], len: 0 }) };
}

struct Cut<'a> {
    e: &'a mut LastError,
}

impl Write for Cut<'_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        let room = CAP - self.e.len;
        let mut take = s.len().min(room);
        while !s.is_char_boundary(take) {
            take -= 1;
        }
        self.e.buf[self.e.len..self.e.len + take].copy_from_slice(&s.as_bytes()[..take]);
        self.e.len += take;
        Ok(())
    }
}

/// Records `args` as this thread's last error and returns `code`. Allocates nothing.
pub(crate) fn fail(code: TautError, args: fmt::Arguments<'_>) -> TautError {
    LAST.with(|l| {
        let mut l = l.borrow_mut();
        l.len = 0;
        let _ = Cut { e: &mut l }.write_fmt(args);
    });
    code
}

/// Copies this thread's last message into `out` (NUL-terminated, cut to fit); returns its full
/// length without the NUL.
pub(crate) fn copy_last(out: &mut [u8]) -> usize {
    LAST.with(|l| {
        let l = l.borrow();
        copy_str(&l.buf[..l.len], out)
    })
}

/// Copies `text` into `out` NUL-terminated (cut to fit, at a UTF-8 boundary); returns the full
/// length of `text`.
pub(crate) fn copy_str(text: &[u8], out: &mut [u8]) -> usize {
    if let Some(room) = out.len().checked_sub(1) {
        let mut take = text.len().min(room);
        while take > 0 && take < text.len() && (text[take] & 0xC0) == 0x80 {
            take -= 1;
        }
        out[..take].copy_from_slice(&text[..take]);
        out[take] = 0;
    }
    text.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_messages_are_cut_at_a_character_boundary() {
        let s = "é".repeat(CAP);
        fail(TautError::Config, format_args!("{s}"));
        let mut out = vec![0u8; 2 * CAP];
        let n = copy_last(&mut out);
        assert!(n <= CAP, "{n}");
        assert!(std::str::from_utf8(&out[..n]).is_ok());
        let mut small = [0xffu8; 4];
        assert_eq!(copy_str("aéb".as_bytes(), &mut small), 4);
        assert_eq!(&small, b"a\xc3\xa9\0");
        let mut tiny = [0xffu8; 3];
        copy_str("aéb".as_bytes(), &mut tiny);
        assert_eq!(&tiny, b"a\0\xff");
    }
}
