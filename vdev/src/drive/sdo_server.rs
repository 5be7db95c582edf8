//! The SDO server (CiA 301 7.2.4): expedited and segmented transfers, aborts, slow and
//! duplicated answers; reads and writes go to the object dictionary (`dictionary`).

use super::VirtualDrive;
use taut_proto::canopen::sdo::{AbortCode, Initiate, SdoRequest, SdoResponse, Segment};

/// Largest object the SDO server moves in one transfer, bytes.
pub(super) const SDO_MAX: usize = 64;

#[derive(Debug, Clone)]
pub(super) enum SdoServer {
    Idle,
    Download { index: u16, sub: u8, buf: [u8; SDO_MAX], len: usize, toggle: bool },
    Upload { index: u16, sub: u8, buf: [u8; SDO_MAX], len: usize, pos: usize, toggle: bool },
}

impl VirtualDrive {
    pub(super) fn respond(&mut self, r: SdoResponse) {
        if let SdoResponse::Abort { .. } = r {
            self.counters.sdo_aborts += 1;
        }
        self.sdo_answers = self.sdo_answers.wrapping_add(1);
        let twice = self.p.sdo_duplicate_every > 0 && self.sdo_answers.is_multiple_of(self.p.sdo_duplicate_every);
        let f = r.encode(self.p.node_id);
        for _ in 0..1 + usize::from(twice) {
            match self.clock {
                Some(now) if !self.p.sdo_delay.is_zero() => self.delayed.push_back((now + self.p.sdo_delay, f)),
                _ => self.send(f),
            }
        }
        if twice {
            self.counters.sdo_duplicates += 1;
        }
    }

    pub(super) fn on_sdo(&mut self, data: &[u8]) {
        let req = match SdoRequest::decode(data) {
            Ok(r) => r,
            Err(e) => {
                self.sdo = SdoServer::Idle;
                let (index, sub) = if data.len() >= 4 { (u16::from_le_bytes([data[1], data[2]]), data[3]) } else { (0, 0) };
                return self.respond(SdoResponse::Abort { index, sub, code: e.abort_code() });
            }
        };
        match (req, self.sdo.clone()) {
            (SdoRequest::Abort { .. }, _) => self.sdo = SdoServer::Idle,
            (SdoRequest::InitiateUpload { index, sub }, _) => {
                self.sdo = SdoServer::Idle;
                match self.read(index, sub) {
                    Err(code) => self.respond(SdoResponse::Abort { index, sub, code }),
                    Ok((buf, len)) if len <= 4 => {
                        let mut d = [0u8; 4];
                        d[..len].copy_from_slice(&buf[..len]);
                        self.respond(SdoResponse::UploadInitiated { index, sub, kind: Initiate::Expedited { data: d, len: len as u8 } })
                    }
                    Ok((buf, len)) => {
                        self.sdo = SdoServer::Upload { index, sub, buf, len, pos: 0, toggle: false };
                        self.respond(SdoResponse::UploadInitiated { index, sub, kind: Initiate::Segmented { size: Some(len as u32) } })
                    }
                }
            }
            (SdoRequest::UploadSegment { toggle }, SdoServer::Upload { index, sub, buf, len, pos, toggle: t }) => {
                if toggle != t {
                    self.sdo = SdoServer::Idle;
                    return self.respond(SdoResponse::Abort { index, sub, code: AbortCode::TOGGLE });
                }
                let n = (len - pos).min(7);
                let mut d = [0u8; 7];
                d[..n].copy_from_slice(&buf[pos..pos + n]);
                let last = pos + n == len;
                self.sdo = if last { SdoServer::Idle } else { SdoServer::Upload { index, sub, buf, len, pos: pos + n, toggle: !t } };
                self.respond(SdoResponse::UploadSegment(Segment { toggle, data: d, len: n as u8, last }))
            }
            (SdoRequest::InitiateDownload { index, sub, kind }, _) => {
                self.sdo = SdoServer::Idle;
                match kind {
                    Initiate::Expedited { data, len } => match self.write(index, sub, &data[..usize::from(len)]) {
                        Ok(()) => self.respond(SdoResponse::DownloadInitiated { index, sub }),
                        Err(code) => self.respond(SdoResponse::Abort { index, sub, code }),
                    },
                    Initiate::Segmented { size } => {
                        if size.is_some_and(|s| s as usize > SDO_MAX) {
                            return self.respond(SdoResponse::Abort { index, sub, code: AbortCode::OUT_OF_MEMORY });
                        }
                        self.sdo = SdoServer::Download { index, sub, buf: [0; SDO_MAX], len: 0, toggle: false };
                        self.respond(SdoResponse::DownloadInitiated { index, sub })
                    }
                }
            }
            (SdoRequest::DownloadSegment(s), SdoServer::Download { index, sub, mut buf, len, toggle }) => {
                let n = usize::from(s.len);
                if s.toggle != toggle {
                    self.sdo = SdoServer::Idle;
                    return self.respond(SdoResponse::Abort { index, sub, code: AbortCode::TOGGLE });
                }
                if len + n > SDO_MAX {
                    self.sdo = SdoServer::Idle;
                    return self.respond(SdoResponse::Abort { index, sub, code: AbortCode::OUT_OF_MEMORY });
                }
                buf[len..len + n].copy_from_slice(&s.data[..n]);
                if s.last {
                    self.sdo = SdoServer::Idle;
                    match self.write(index, sub, &buf[..len + n]) {
                        Ok(()) => self.respond(SdoResponse::DownloadSegmentAck { toggle }),
                        Err(code) => self.respond(SdoResponse::Abort { index, sub, code }),
                    }
                } else {
                    self.sdo = SdoServer::Download { index, sub, buf, len: len + n, toggle: !toggle };
                    self.respond(SdoResponse::DownloadSegmentAck { toggle })
                }
            }
            (_, _) => {
                self.sdo = SdoServer::Idle;
                self.respond(SdoResponse::Abort { index: 0, sub: 0, code: AbortCode::COMMAND })
            }
        }
    }
}
