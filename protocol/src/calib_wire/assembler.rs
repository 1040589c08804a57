//! The receiving end of `CALIB_PARAMS`: a set arrives as four pages, and a
//! parameter store must gather them and check SET_CRC before using it.

use super::CalibWire;
use super::messages::{ParamSet, ParamsData, ParamsPage};

/// Collects the four pages of one `CALIB_PARAMS` set, as a parameter store
/// does, and yields the set once all arrived with a matching SET_CRC.
#[derive(Debug, Default, Clone)]
pub struct ParamsAssembler {
    version: Option<u16>,
    pages: [Option<ParamsData>; 4],
}

impl ParamsAssembler {
    /// Adds a page; pages of another version restart the set. Returns the set
    /// when complete: `Ok` if SET_CRC matches, `Err(set)` if not.
    pub fn push(
        &mut self,
        wire: &CalibWire,
        page: ParamsPage,
    ) -> Option<std::result::Result<ParamSet, ParamSet>> {
        if self.version != Some(page.version) {
            *self = Self {
                version: Some(page.version),
                ..Self::default()
            };
        }
        let slot = match page.data {
            ParamsData::TreadCrc { .. } => 0,
            ParamsData::Diameters { .. } => 1,
            ParamsData::RatioGain { .. } => 2,
            ParamsData::Offset { .. } => 3,
        };
        self.pages[slot] = Some(page.data);
        let [
            Some(ParamsData::TreadCrc {
                rear_tread_m,
                set_crc,
            }),
            Some(ParamsData::Diameters {
                rear_left_diameter_m,
                rear_right_diameter_m,
            }),
            Some(ParamsData::RatioGain {
                diameter_ratio,
                steer_gain,
            }),
            Some(ParamsData::Offset { steer_offset_rad }),
        ] = self.pages
        else {
            return None;
        };
        let set = ParamSet {
            version: page.version,
            rear_tread_m,
            rear_left_diameter_m,
            rear_right_diameter_m,
            diameter_ratio,
            steer_gain,
            steer_offset_rad,
        };
        *self = Self::default();
        Some(match wire.set_crc(&set) {
            Ok(crc) if crc == set_crc => Ok(set),
            _ => Err(set),
        })
    }
}
