//! PDOs (CiA 301 7.2.2, 7.5.2.35-38): the mapping rules a real drive enforces, the factory
//! mapping, RPDO reception and the SYNC-driven engine (latched RPDOs applied, TPDOs sent).

use super::dictionary::{object_exists, FOLLOWING_ERROR};
use super::VirtualDrive;
use std::time::Instant;
use taut_proto::can::Frame;
use taut_proto::canopen::emcy::{self, Emcy};
use taut_proto::canopen::od;
use taut_proto::canopen::pdo::{self, MapEntry, COB_ID_INVALID};
use taut_proto::canopen::sdo::AbortCode;
use taut_proto::canopen::NodeId;

/// CiA 301: general parameter incompatibility (here: sub 0 counts an empty mapping entry).
const PARAM_INCOMPATIBLE: AbortCode = AbortCode(0x0604_0043);

/// The drive's mappable objects: index, sub-index, bits, mappable into an RPDO, into a TPDO.
const MAPPABLE: &[(u16, u8, u8, bool, bool)] = &[
    (od::ERROR_CODE, 0, 16, false, true),
    (od::CONTROLWORD, 0, 16, true, false),
    (od::STATUSWORD, 0, 16, false, true),
    (od::MODES_OF_OPERATION, 0, 8, true, false),
    (od::MODES_OF_OPERATION_DISPLAY, 0, 8, false, true),
    (od::POSITION_ACTUAL, 0, 32, false, true),
    (od::VELOCITY_ACTUAL, 0, 32, false, true),
    (od::TARGET_TORQUE, 0, 16, true, false),
    (od::TORQUE_ACTUAL, 0, 16, false, true),
    (od::TARGET_POSITION, 0, 32, true, true),
    (FOLLOWING_ERROR, 0, 32, false, true),
];

#[derive(Debug, Clone, Copy)]
pub(super) struct PdoSlot {
    pub(super) cob_id: u32,
    pub(super) trans_type: u8,
    pub(super) map: [u32; 8],
    pub(super) count: u8,
}

impl PdoSlot {
    pub(super) fn valid(&self) -> bool {
        self.cob_id & COB_ID_INVALID == 0
    }
    pub(super) fn entries(&self) -> heapless::Vec<MapEntry, 8> {
        self.map[..usize::from(self.count.min(8))].iter().filter_map(|&v| MapEntry::decode(v)).collect()
    }

    fn with(cob_id: u32, trans_type: u8, entries: &[MapEntry]) -> PdoSlot {
        let mut map = [0u32; 8];
        for (m, e) in map.iter_mut().zip(entries) {
            *m = e.encode();
        }
        PdoSlot { cob_id, trans_type, map, count: entries.len() as u8 }
    }

    /// CiA 301 7.5.2.35 / 7.5.2.37: a write to the communication parameter.
    pub(super) fn write_comm(&mut self, sub: u8, v: u32) -> Result<(), AbortCode> {
        match sub {
            1 => {
                let valid = v & COB_ID_INVALID == 0;
                // 11-bit ids only (bit 29 = extended frame), the id fixed while valid, and no
                // valid PDO without a mapping.
                if v & 0x3FFF_F800 != 0 || (valid && self.valid() && (v & 0x7FF) != (self.cob_id & 0x7FF)) || (valid && self.count == 0) {
                    return Err(AbortCode::INVALID_VALUE);
                }
                self.cob_id = v;
                Ok(())
            }
            2 => {
                let t = v as u8;
                if (241..=251).contains(&t) {
                    return Err(AbortCode::INVALID_VALUE);
                }
                self.trans_type = t;
                Ok(())
            }
            0 => Err(AbortCode::READ_ONLY),
            _ => Err(AbortCode::NO_SUBINDEX),
        }
    }

    /// CiA 301 7.5.2.36 / 7.5.2.38: a write to the mapping parameter.
    pub(super) fn write_map(&mut self, rx: bool, sub: u8, v: u32) -> Result<(), AbortCode> {
        if sub > 8 {
            return Err(AbortCode::NO_SUBINDEX);
        }
        // The mapping changes only while the PDO is invalid, and entries only while sub 0 is 0.
        if self.valid() || (sub > 0 && self.count != 0) {
            return Err(AbortCode::UNSUPPORTED_ACCESS);
        }
        if sub == 0 {
            let n = v as u8;
            if n > 8 {
                return Err(AbortCode::PDO_TOO_LONG);
            }
            let mut bits = 0u32;
            for &m in &self.map[..usize::from(n)] {
                if MapEntry::decode(m).is_none() {
                    return Err(PARAM_INCOMPATIBLE);
                }
                bits += m & 0xFF;
            }
            if bits > 64 {
                return Err(AbortCode::PDO_TOO_LONG);
            }
            self.count = n;
            return Ok(());
        }
        if v != 0 {
            let e = MapEntry::decode(v).ok_or(AbortCode::NOT_MAPPABLE)?;
            mapping_check(rx, e)?;
        }
        self.map[usize::from(sub - 1)] = v;
        Ok(())
    }
}

/// Whether `e` may be mapped into an RPDO (`rx`) or a TPDO of this drive.
fn mapping_check(rx: bool, e: MapEntry) -> Result<(), AbortCode> {
    match MAPPABLE.iter().find(|m| m.0 == e.index && m.1 == e.sub) {
        Some(&(_, _, bits, r, t)) if bits == e.bits && if rx { r } else { t } => Ok(()),
        Some(_) => Err(AbortCode::NOT_MAPPABLE),
        None if MAPPABLE.iter().any(|m| m.0 == e.index) => Err(AbortCode::NO_SUBINDEX),
        None if object_exists(e.index) => Err(AbortCode::NOT_MAPPABLE),
        None => Err(AbortCode::NO_OBJECT),
    }
}

/// The factory PDO configuration (what reset communication restores): deliberately not taut's,
/// as on real drives. RPDO1 0x200+n controlword + mode, RPDO2 0x300+n controlword + target
/// position, TPDO1 0x180+n statusword + mode display (event driven), TPDO2 0x280+n statusword +
/// position actual on every SYNC; PDOs 3 and 4 invalid and empty.
pub(super) fn factory_pdos(node: NodeId) -> ([PdoSlot; 4], [PdoSlot; 4]) {
    let n = u32::from(node);
    let e = MapEntry::new;
    let mut rpdo = [PdoSlot { cob_id: COB_ID_INVALID, trans_type: 255, map: [0; 8], count: 0 }; 4];
    let mut tpdo = rpdo;
    for k in 0..4u32 {
        rpdo[k as usize].cob_id = (0x200 + 0x100 * k + n) | COB_ID_INVALID;
        tpdo[k as usize].cob_id = (0x180 + 0x100 * k + n) | COB_ID_INVALID;
    }
    rpdo[0] = PdoSlot::with(0x200 + n, 255, &[e(od::CONTROLWORD, 0, 16), e(od::MODES_OF_OPERATION, 0, 8)]);
    rpdo[1] = PdoSlot::with(0x300 + n, 255, &[e(od::CONTROLWORD, 0, 16), e(od::TARGET_POSITION, 0, 32)]);
    tpdo[0] = PdoSlot::with(0x180 + n, 255, &[e(od::STATUSWORD, 0, 16), e(od::MODES_OF_OPERATION_DISPLAY, 0, 8)]);
    tpdo[1] = PdoSlot::with(0x280 + n, 1, &[e(od::STATUSWORD, 0, 16), e(od::POSITION_ACTUAL, 0, 32)]);
    (rpdo, tpdo)
}

impl VirtualDrive {
    pub(super) fn on_rpdo(&mut self, k: usize, f: &Frame) {
        let entries = self.rpdo[k].entries();
        if f.data().len() < usize::from(pdo::byte_len(&entries)) {
            // CiA 301 7.2.2.2: a too-short RPDO is not processed; report it.
            self.counters.short_rpdos += 1;
            self.send(emcy::encode(self.p.node_id, &Emcy { code: 0x8210, register: 0x11, vendor: [0; 5] }));
            return;
        }
        let mut d = [0u8; 8];
        d[..f.data().len()].copy_from_slice(f.data());
        if self.rpdo[k].trans_type >= 254 {
            self.apply_rpdo(k, &d, f.dlc);
        } else {
            self.latched[k] = Some((d, f.dlc));
        }
    }

    pub(super) fn apply_rpdo(&mut self, k: usize, d: &[u8; 8], dlc: u8) {
        let entries = self.rpdo[k].entries();
        let mut vals: heapless::Vec<(u16, u64, u8), 8> = heapless::Vec::new();
        let _ = pdo::unpack(&entries, &d[..usize::from(dlc)], |index, _, raw, bits| {
            let _ = vals.push((index, raw, bits));
        });
        for (index, raw, bits) in vals {
            match index {
                od::CONTROLWORD => self.on_controlword(raw as u16),
                od::TARGET_POSITION => self.target_position = pdo::sign_extend(raw, bits) as i32,
                od::TARGET_TORQUE => self.target_torque = pdo::sign_extend(raw, bits) as i16,
                od::MODES_OF_OPERATION => self.mode = raw as u8 as i8,
                _ => {}
            }
        }
    }

    pub(super) fn on_sync(&mut self, now: Instant) {
        self.counters.syncs += 1;
        for k in 0..4 {
            if let Some((d, dlc)) = self.latched[k].take() {
                self.apply_rpdo(k, &d, dlc);
            }
        }
        let dt = self.last_sync.map_or(0.0, |t| now.saturating_duration_since(t).as_secs_f64().min(0.1));
        self.last_sync = Some(now);
        let before = self.position;
        if !self.external {
            self.step_motion(dt);
        }
        // Velocity over the last SYNC period (also when the plant owns the position).
        if dt > 0.0 {
            self.velocity = ((self.position - before) / dt).round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
        }
        for k in 0..4 {
            let slot = self.tpdo[k];
            if !slot.valid() || !(1..=240).contains(&slot.trans_type) {
                continue;
            }
            self.sync_count[k] += 1;
            if self.sync_count[k] < slot.trans_type {
                continue;
            }
            self.sync_count[k] = 0;
            let entries = slot.entries();
            let mut data = [0u8; 8];
            let sw = self.statusword();
            let (pos, tq, mode, err) = (self.position() as u32 as u64, self.torque as u16 as u64, self.mode as u8 as u64, self.error_code);
            if let Ok(dlc) = pdo::pack(&entries, &mut data, |index, _| match index {
                od::STATUSWORD => u64::from(sw),
                od::POSITION_ACTUAL => pos,
                od::TORQUE_ACTUAL => tq,
                od::MODES_OF_OPERATION_DISPLAY => mode,
                od::ERROR_CODE => u64::from(err),
                od::TARGET_POSITION => self.target_position as u32 as u64,
                od::VELOCITY_ACTUAL => self.velocity as u32 as u64,
                FOLLOWING_ERROR => (self.target_position.wrapping_sub(self.position())) as u32 as u64,
                _ => 0,
            }) {
                self.send(Frame::new((slot.cob_id & 0x7FF) as u16, &data[..usize::from(dlc)]));
            }
        }
    }
}
