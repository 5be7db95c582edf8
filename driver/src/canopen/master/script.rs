//! The configuration script: the SDO steps that bring a node from its boot-up to NMT start,
//! and the master's side of running them (one step at a time, retries, failures).

use super::node::{Axis, Identity};
use super::{Master, NodeConfig, NodeEvent, NodeFailure, Phase, Problem, Supervision};
use std::time::Instant;
use taut_proto::canopen::cia402::{self, PowerState};
use taut_proto::canopen::nmt::NmtCommand;
use taut_proto::canopen::od;
use taut_proto::canopen::pdo::{self, SdoWrite};
use taut_proto::canopen::sdo::{AbortCode, SdoOutcome};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Field {
    DeviceType,
    Vendor,
    Product,
    Revision,
    Serial,
    Name,
    /// 0x6041: the CiA 402 state a previous run left the drive in.
    Statusword,
    /// 0x6064: where it stands, so that the first target is that.
    Position,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Step {
    Upload {
        index: u16,
        sub: u8,
        field: Field,
        required: bool,
    },
    Download(SdoWrite),
    /// Brings a drive found powered to power stage off by SDO before anything else is written:
    /// CiA 402 transition 8 (shutdown) from switched on / operation enabled, 12 (disable voltage)
    /// from quick stop active. Skipped for drives off or in fault (the operator resets a fault).
    PowerOff,
    /// A download a drive may refuse because the object does not exist (an unused PDO).
    Optional(SdoWrite),
    /// Upload and compare with the value: the read-back of the PDO configuration.
    Verify(SdoWrite),
}

/// The configuration script of one node, in order: identity, statusword and position read,
/// a powered drive switched off, heartbeat producer, supervision by the drive, then the PDOs.
pub(super) fn script(cfg: &NodeConfig, sup: Supervision) -> Vec<Step> {
    let mut steps = vec![
        Step::Upload { index: od::DEVICE_TYPE, sub: 0, field: Field::DeviceType, required: true },
        Step::Upload { index: od::IDENTITY, sub: 1, field: Field::Vendor, required: true },
        Step::Upload { index: od::IDENTITY, sub: 2, field: Field::Product, required: false },
        Step::Upload { index: od::IDENTITY, sub: 3, field: Field::Revision, required: false },
        Step::Upload { index: od::IDENTITY, sub: 4, field: Field::Serial, required: false },
        Step::Upload { index: od::DEVICE_NAME, sub: 0, field: Field::Name, required: false },
        Step::Upload { index: od::STATUSWORD, sub: 0, field: Field::Statusword, required: true },
        Step::Upload { index: od::POSITION_ACTUAL, sub: 0, field: Field::Position, required: true },
        Step::PowerOff,
        Step::Download(SdoWrite::u16(od::HEARTBEAT_PRODUCER, 0, cfg.heartbeat_ms)),
        // Supervision of taut by the drive: abort connection option first, then the consumer
        // (which starts watching at taut's next heartbeat).
        Step::Download(SdoWrite::u16(od::ABORT_CONNECTION, 0, sup.abort_connection as u16)),
        Step::Download(SdoWrite::u32(od::HEARTBEAT_CONSUMER, 1, u32::from(sup.node_id & 0x7F) << 16 | u32::from(sup.consumer_time_ms()))),
    ];
    pdo_steps(cfg, &mut steps);
    steps
}

/// The PDO part of a node's configuration steps: every PDO of the map the CiA 301 way, the
/// unused PDOs of the predefined connection set off, the PDO configuration read back, and the
/// mode by SDO when no RPDO carries it.
fn pdo_steps(cfg: &NodeConfig, steps: &mut Vec<Step>) {
    let n = cfg.node_id;
    for p in cfg.pdos.iter() {
        steps.extend(p.config_writes(n).map(Step::Download));
    }
    for dir in [pdo::Direction::Rx, pdo::Direction::Tx] {
        for num in (0..4).filter(|&k| !cfg.pdos.has(dir, k)) {
            steps.push(Step::Optional(pdo::disable_write(dir, num, n)));
        }
    }
    for p in cfg.pdos.iter() {
        steps.extend(p.readback(n).map(Step::Verify));
    }
    if !cfg.pdos.maps_mode() {
        steps.push(Step::Download(SdoWrite::u8(od::MODES_OF_OPERATION, 0, cfg.mode.code() as u8)));
    }
}

impl Master {
    pub(super) fn begin_config(&mut self, k: usize, now: Instant) {
        let n = &mut self.nodes[k];
        n.heard_since_reset = None;
        n.sdo.cancel();
        n.hb.reset();
        n.phase = Phase::Configuring;
        n.step = 0;
        n.tries = 0;
        n.identity = Identity::default();
        n.axis = Axis::new(n.cfg.mode);
        self.next_step(k, now);
    }

    pub(super) fn next_step(&mut self, k: usize, now: Instant) {
        let n = &mut self.nodes[k];
        if n.phase != Phase::Configuring || n.sdo.is_busy() {
            return;
        }
        let node = n.cfg.node_id;
        match n.steps.get(n.step).copied() {
            Some(Step::Upload { index, sub, .. } | Step::Verify(SdoWrite { index, sub, .. })) => {
                let _ = n.sdo.upload(index, sub, now);
            }
            Some(Step::PowerOff) => {
                let cw = match n.axis.state {
                    Some(s @ (PowerState::OperationEnabled | PowerState::SwitchedOn)) => Some((s, cia402::CW_SHUTDOWN)),
                    Some(s @ PowerState::QuickStopActive) => Some((s, cia402::CW_DISABLE_VOLTAGE)),
                    _ => None,
                };
                let Some((state, cw)) = cw else {
                    n.step += 1;
                    return self.next_step(k, now);
                };
                let _ = n.sdo.download(od::CONTROLWORD, 0, &cw.to_le_bytes(), false, now);
                self.event(NodeEvent::FoundPowered { node, state });
            }
            Some(Step::Download(w) | Step::Optional(w)) => {
                let (b, len) = w.bytes();
                let _ = n.sdo.download(w.index, w.sub, &b[..len], false, now);
            }
            None => {
                n.phase = Phase::Starting;
                // Watch the heartbeat from now on: 0x1017 has been written.
                n.hb.on_heartbeat(now);
                self.event(NodeEvent::Configured { node });
                self.send_nmt(NmtCommand::Start, node);
                return;
            }
        }
        self.flush_sdo(k);
    }

    pub(super) fn on_sdo_outcome(&mut self, k: usize, o: SdoOutcome, now: Instant) {
        let node = self.nodes[k].cfg.node_id;
        let Some(step) = self.nodes[k].steps.get(self.nodes[k].step).copied() else { return };
        if self.nodes[k].phase != Phase::Configuring {
            return;
        }
        match o {
            SdoOutcome::Uploaded { len, .. } => {
                let n = &mut self.nodes[k];
                let d = n.sdo.data();
                let mut b = [0u8; 4];
                b[..len.min(4)].copy_from_slice(&d[..len.min(4)]);
                let v = u32::from_le_bytes(b);
                if let Step::Verify(w) = step {
                    // Compared over the written width (a drive may answer an expedited upload as 4
                    // bytes). Of a COB-ID only the valid bit and the 11-bit id count: CiA 301 lets a
                    // drive report bits 30 and 29 as it implements them.
                    let cob = w.sub == 1 && matches!(w.index, 0x1400..=0x15FF | 0x1800..=0x19FF);
                    let mask = match (cob, w.len) {
                        (true, _) => pdo::COB_ID_INVALID | 0x7FF,
                        (false, 4..) => u32::MAX,
                        (false, n) => (1u32 << (8 * u32::from(n))) - 1,
                    };
                    if len < usize::from(w.len) || v & mask != w.value & mask {
                        return self.fail(k, NodeFailure::Readback { index: w.index, sub: w.sub, expected: w.value, found: v });
                    }
                }
                if let Step::Upload { field, .. } = step {
                    match field {
                        Field::DeviceType => n.identity.device_type = Some(v),
                        Field::Vendor => n.identity.vendor = Some(v),
                        Field::Product => n.identity.product = Some(v),
                        Field::Revision => n.identity.revision = Some(v),
                        Field::Serial => n.identity.serial = Some(v),
                        Field::Statusword => {
                            n.axis.statusword = v as u16;
                            n.axis.state = PowerState::from_statusword(v as u16);
                        }
                        Field::Position => {
                            // The first RPDO commands where the drive stands.
                            n.axis.position = v as i32;
                            n.axis.target_position = v as i32;
                        }
                        Field::Name => {
                            let m = len.min(32);
                            n.name[..m].copy_from_slice(&d[..m]);
                            // Trim trailing NULs some drives pad with; keep valid UTF-8.
                            let mut m = m;
                            while m > 0 && n.name[m - 1] == 0 {
                                m -= 1;
                            }
                            while std::str::from_utf8(&n.name[..m]).is_err() {
                                m -= 1;
                            }
                            n.name_len = m as u8;
                        }
                    }
                    let check = match field {
                        Field::Vendor => n.cfg.vendor_id.map(|e| (1, e)),
                        Field::Product => n.cfg.product_code.map(|e| (2, e)),
                        _ => None,
                    };
                    if let Some((sub, expected)) = check {
                        if expected != v {
                            return self.fail(k, NodeFailure::WrongDevice { sub, expected, found: v });
                        }
                    }
                    if field == Field::Name {
                        let identity = n.identity;
                        self.event(NodeEvent::Identified { node, identity });
                    }
                }
                self.advance(k, now);
            }
            SdoOutcome::Downloaded { .. } => self.advance(k, now),
            SdoOutcome::Aborted(a) => {
                self.counters.sdo_aborts += 1;
                let required = match step {
                    Step::Upload { required, field, .. } => {
                        if field == Field::Name {
                            let identity = self.nodes[k].identity;
                            self.event(NodeEvent::Identified { node, identity });
                        }
                        required
                    }
                    Step::Download(_) | Step::PowerOff | Step::Verify(_) => true,
                    // An unused PDO the drive does not have need not be switched off.
                    Step::Optional(_) => !(a.by_server && matches!(a.code, AbortCode::NO_OBJECT | AbortCode::NO_SUBINDEX)),
                };
                if a.code == AbortCode::TIMEOUT && !a.by_server {
                    self.counters.sdo_timeouts += 1;
                    self.problem(Problem::SdoTimeout, u32::from(0x600 + u16::from(node)));
                } else {
                    self.problem(Problem::SdoAbort, u32::from(0x580 + u16::from(node)));
                }
                self.event(NodeEvent::SdoAborted { node, abort: a });
                // The client gives up (timeout, garbled answer): try again. The server refuses:
                // trying again would get the same answer.
                if !a.by_server && self.nodes[k].tries < self.cfg_retries {
                    self.nodes[k].tries += 1;
                    self.counters.sdo_retries += 1;
                    self.next_step(k, now);
                } else if required {
                    self.fail(k, NodeFailure::Sdo(a));
                } else {
                    self.advance(k, now);
                }
            }
        }
    }

    fn advance(&mut self, k: usize, now: Instant) {
        self.nodes[k].step += 1;
        self.nodes[k].tries = 0;
        self.next_step(k, now);
    }

    fn fail(&mut self, k: usize, failure: NodeFailure) {
        let n = &mut self.nodes[k];
        n.phase = Phase::Failed(failure);
        n.sdo.cancel();
        let node = n.cfg.node_id;
        self.event(NodeEvent::Failed { node, failure });
    }
}
