//! How production cars put one quantity on the bus, and how `[signals]`
//! says so (issue #32).
//!
//! A quantity is one DBC signal, or a form of several signals of one message:
//!
//! - **magnitude and sign**: VW sends the steering-wheel angle and the yaw
//!   rate as an unsigned magnitude (`LWI_01.LWI_Lenkradwinkel`) beside a sign
//!   bit (`LWI_VZ_Lenkradwinkel`); `negative_when` names the sign signal's raw
//!   value that makes it negative (1 by default; 0 for the other polarity);
//! - **sum**: a coarse and a fine signal added (Toyota's `STEER_ANGLE` in
//!   1.5° steps plus `STEER_FRACTION` in 0.1° steps);
//! - **unit override**: `unit = "km/h"` when the DBC's unit is missing or
//!   wrong. The spellings of opendbc's DBC files are recognised
//!   ([`Unit::parse`]: VW's `Unit_KiloMeterPerHour`, `Unit_DegreOfArc`, ...).
//!
//! ```toml
//! [signals]
//! steering = { signal = "LWI_01.LWI_Lenkradwinkel", sign = "LWI_01.LWI_VZ_Lenkradwinkel" }
//! steering = { sum = ["STEER_ANGLE_SENSOR.STEER_ANGLE", "STEER_ANGLE_SENSOR.STEER_FRACTION"] }
//! rear_left = { signal = "ESP_19.ESP_HL_Radgeschw_02", unit = "km/h" }
//! direction = { signal = "Getriebe_11.GE_Fahrstufe", reverse = ["R"] }
//! ```
//!
//! Wheel-speed sensors mostly report magnitudes: `direction` names the
//! signal (a direction bit, or the gear) whose listed values mean reversing,
//! so that the speeds are signed.

use canodom_dbc::{Database, SignalHandle};
use serde::Deserialize;
use std::fmt;

/// The physical units canodom converts, each with every spelling met in
/// opendbc's DBC files.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Unit {
    /// km/h (`km/h`, `kph`, `Unit_KiloMeterPerHour`, ...).
    KilometresPerHour,
    /// m/s (`m/s`, `Unit_MeterPerSecond`, ...).
    MetresPerSecond,
    /// Miles per hour (`mph`).
    MilesPerHour,
    /// Degrees (`deg`, `°`, `Unit_DegreOfArc`, ...).
    Degrees,
    /// Radians (`rad`).
    Radians,
    /// Degrees per second (`deg/s`, `°/s`, `Unit_DegreOfArcPerSecon`, ...).
    DegreesPerSecond,
    /// Radians per second (`rad/s`).
    RadiansPerSecond,
}

/// What a unit measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quantity {
    /// A speed.
    Speed,
    /// An angle.
    Angle,
    /// An angular rate.
    AngularRate,
}

impl fmt::Display for Quantity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Speed => "a speed (km/h, m/s or mph)",
            Self::Angle => "an angle (deg or rad)",
            Self::AngularRate => "an angular rate (deg/s or rad/s)",
        })
    }
}

impl Unit {
    /// The unit a DBC or a configuration spells `text`, if canodom knows it.
    /// Case, blanks, VW's `Unit_` prefix and plural endings do not matter;
    /// VW's spellings cut at 24 characters (`...PerSecon`) are recognised.
    pub fn parse(text: &str) -> Option<Self> {
        let lower = text.trim().to_lowercase().replace([' ', '_', '-'], "");
        let t = lower
            .strip_prefix("unit")
            .unwrap_or(&lower)
            .replace("°grad", "deg")
            .replace('°', "deg");
        Some(match t.as_str() {
            "km/h" | "kph" | "kmh" | "kmph" | "km/hr" | "km^h" | "kilometer/hour"
            | "kilometerperhour" | "kilometersperhour" | "kilometreperhour"
            | "kilometresperhour" => Self::KilometresPerHour,
            "m/s" | "m/sec" | "mps" | "meters/sec" | "meterpersecond" | "meterpersecon"
            | "meterspersecond" | "metrepersecond" | "metrespersecond" => Self::MetresPerSecond,
            "mph" | "mi/h" | "mileperhour" | "milesperhour" => Self::MilesPerHour,
            "deg" | "degs" | "degree" | "degrees" | "degreofarc" | "degreeofarc" | "grad"
            | "degrad" => Self::Degrees,
            "rad" | "radian" | "radians" => Self::Radians,
            "deg/s"
            | "deg/sec"
            | "deg/sek"
            | "degree/s"
            | "degrees/s"
            | "degrees/sec"
            | "degrees/second"
            | "degré/s"
            | "dps"
            | "degps"
            | "grad/s"
            | "grad/sec"
            | "degrad/s"
            | "degreofarcpersecon"
            | "degreofarcpersecond"
            | "degreeofarcpersecond"
            | "degreepersecond"
            | "degreespersecond" => Self::DegreesPerSecond,
            "rad/s" | "rad/sec" | "radps" | "radians/sec" | "radians/second"
            | "radianpersecond" | "radianspersecond" => Self::RadiansPerSecond,
            _ => return None,
        })
    }

    /// What it measures.
    pub fn quantity(self) -> Quantity {
        match self {
            Self::KilometresPerHour | Self::MetresPerSecond | Self::MilesPerHour => Quantity::Speed,
            Self::Degrees | Self::Radians => Quantity::Angle,
            Self::DegreesPerSecond | Self::RadiansPerSecond => Quantity::AngularRate,
        }
    }

    /// One unit in SI (m/s, rad, rad/s).
    pub fn si_per_unit(self) -> f64 {
        match self {
            Self::KilometresPerHour => 1.0 / 3.6,
            Self::MetresPerSecond | Self::Radians | Self::RadiansPerSecond => 1.0,
            Self::MilesPerHour => 0.447_04,
            Self::Degrees | Self::DegreesPerSecond => std::f64::consts::PI / 180.0,
        }
    }
}

/// A quantity's signal as `[signals]` writes it: `"MESSAGE.SIGNAL"` or a
/// table (see the module doc).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RawSignal {
    /// The signal, or the magnitude when `sign` is given.
    pub signal: Option<String>,
    /// Two signals added: coarse then fine (instead of `signal`).
    pub sum: Option<Vec<String>>,
    /// The sign signal of a magnitude.
    pub sign: Option<String>,
    /// The sign signal's raw value that means negative (default 1).
    pub negative_when: Option<u64>,
    /// The unit, over the DBC's.
    pub unit: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSignalTable {
    signal: Option<String>,
    sum: Option<Vec<String>>,
    sign: Option<String>,
    negative_when: Option<u64>,
    unit: Option<String>,
}

impl RawSignal {
    /// A plain `"MESSAGE.SIGNAL"`.
    pub fn plain(path: &str) -> Self {
        Self {
            signal: Some(path.to_owned()),
            ..Self::default()
        }
    }

    /// The path the quantity is first named by (for messages).
    pub fn name(&self) -> String {
        match (&self.signal, &self.sum) {
            (Some(s), _) => s.clone(),
            (None, Some(parts)) => parts.join(" + "),
            (None, None) => String::new(),
        }
    }
}

impl<'de> Deserialize<'de> for RawSignal {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = RawSignal;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(
                    "\"MESSAGE.SIGNAL\" or a table with signal (or sum = [coarse, fine]), \
                     and optionally sign, negative_when, unit",
                )
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<RawSignal, E> {
                Ok(RawSignal::plain(v))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                map: A,
            ) -> Result<RawSignal, A::Error> {
                let t =
                    RawSignalTable::deserialize(serde::de::value::MapAccessDeserializer::new(map))?;
                Ok(RawSignal {
                    signal: t.signal,
                    sum: t.sum,
                    sign: t.sign,
                    negative_when: t.negative_when,
                    unit: t.unit,
                })
            }
        }
        d.deserialize_any(Visitor)
    }
}

/// A value of a direction or gear signal: raw, or a name of its DBC value table.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(untagged)]
pub enum RawValue {
    /// The raw value.
    Raw(u64),
    /// A name from the signal's `VAL_` table (`"R"`), case-insensitive.
    Name(String),
}

/// `[signals] direction`: the signal whose values say the car reverses.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawDirection {
    /// `MESSAGE.SIGNAL` of a direction bit or the gear, or two of them.
    pub signal: DirectionPaths,
    /// The values that mean reversing.
    pub reverse: Vec<RawValue>,
}

/// `signal` of `[signals] direction`: one `MESSAGE.SIGNAL`, or the two
/// messages a car line sends its gear in, one per gearbox (Honda:
/// `GEARBOX_AUTO` on automatics, `GEARBOX_CVT` on CVTs, as openpilot's
/// honda carstate chooses by the model): the gear is read from whichever is
/// on the bus (the latest frame of either).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(untagged)]
pub enum DirectionPaths {
    /// `signal = "MESSAGE.SIGNAL"`.
    One(String),
    /// `signal = ["GEARBOX_AUTO.GEAR_SHIFTER", "GEARBOX_CVT.GEAR_SHIFTER"]`.
    Either(Vec<String>),
}

impl DirectionPaths {
    /// The paths, in the file's order.
    pub fn paths(&self) -> &[String] {
        match self {
            Self::One(p) => std::slice::from_ref(p),
            Self::Either(v) => v,
        }
    }
}

impl From<&str> for DirectionPaths {
    fn from(path: &str) -> Self {
        Self::One(path.to_owned())
    }
}

/// A sign signal: which raw value means negative.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SignBit {
    /// The sign signal.
    pub handle: SignalHandle,
    /// Its raw value that makes the quantity negative.
    pub negative_raw: u64,
}

/// A quantity resolved against the DBC: one signal, or a magnitude with a
/// sign, or a sum; all in one message.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SignalForm {
    /// The signal, the magnitude or the coarse part.
    pub main: SignalHandle,
    /// The fine part added to `main`.
    pub fine: Option<SignalHandle>,
    /// The sign of a magnitude.
    pub sign: Option<SignBit>,
}

impl SignalForm {
    /// One plain signal.
    pub fn plain(main: SignalHandle) -> Self {
        Self {
            main,
            fine: None,
            sign: None,
        }
    }

    /// The quantity in `data`, in the signals' unit; `None` when a signal
    /// does not fit the payload.
    #[inline]
    pub fn decode(&self, data: &[u8]) -> Option<f64> {
        let mut v = self.main.decode(data)?;
        if let Some(fine) = &self.fine {
            v += fine.decode(data)?;
        }
        if let Some(sign) = &self.sign
            && sign.handle.raw(data)? == sign.negative_raw
        {
            v = -v;
        }
        Some(v)
    }

    /// Writes `value` (in the signals' unit) into `data`, saturating at the
    /// signals' range; false when a signal does not fit the payload.
    pub fn encode(&self, value: f64, data: &mut [u8]) -> bool {
        let magnitude = match &self.sign {
            Some(sign) => {
                let negative = value < 0.0;
                let positive_raw = u64::from(sign.negative_raw == 0);
                let raw = if negative {
                    sign.negative_raw
                } else {
                    positive_raw
                };
                if !sign.handle.encode_raw(raw, data) {
                    return false;
                }
                value.abs()
            }
            None => value,
        };
        match &self.fine {
            None => self.main.encode_saturating(magnitude, data),
            Some(fine) => {
                let step = self.main.raw_to_scaled(1) - self.main.raw_to_scaled(0);
                let coarse = if step == 0.0 {
                    0.0
                } else {
                    (magnitude / step).round() * step
                };
                self.main.encode_saturating(coarse, data)
                    && fine.encode_saturating(magnitude - coarse, data)
            }
        }
    }

    /// The smallest step of the quantity, in the signals' unit.
    pub fn quantum(&self) -> f64 {
        let h = self.fine.unwrap_or(self.main);
        (h.raw_to_scaled(1) - h.raw_to_scaled(0)).abs()
    }

    /// Whether the form is more than one plain signal.
    pub fn is_plain(&self) -> bool {
        self.fine.is_none() && self.sign.is_none()
    }
}

/// Where a sensor's reading says it may be saturated: at (or within two
/// steps of) an end of its DBC signal's range, where a real sensor holds
/// its reading when the quantity passes the range (issue #45: a Hyundai
/// gyro's ±40.95 °/s end read through a tight turn cost a quarter of the
/// distance, silently).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Saturation {
    /// The range's ends, in the form's unit (signed: a magnitude's range
    /// mirrored by its sign).
    pub range: (f64, f64),
    /// A reading at or below this is saturated (−∞: the low end is 0 or
    /// positive, which a rate holds without being saturated).
    pub below: f64,
    /// A reading at or above this is saturated (+∞ likewise).
    pub above: f64,
}

impl Saturation {
    /// Steps of the signal within which a reading counts as at the end: a
    /// reading held at the end may still dither by a step.
    const STEPS: f64 = 2.0;

    /// The range of `form` in `db`: the raw bits' range, narrowed by the
    /// DBC's `[min|max]` where that end is non-zero and inside the bits'
    /// (opendbc's Toyota `YAW_RATE` states `[0|65535]`: a 0 minimum is no
    /// range and 65535 is past its 10 bits; VW's magnitude ends at its
    /// stated 163.82 a step short of its bits').
    pub fn of(db: &Database, form: &SignalForm) -> Self {
        let def = |h: SignalHandle| &db.messages()[h.message_index()].signals()[h.signal_index()];
        let ends = |h: SignalHandle| {
            let signal = def(h);
            let (mut lo, mut hi) = signal.encodable_range();
            let (min, max) = (signal.min(), signal.max());
            if min < max {
                if min != 0.0 && min > lo && min < hi {
                    lo = min;
                }
                if max != 0.0 && max < hi && max > lo {
                    hi = max;
                }
            }
            (lo, hi)
        };
        let (mut lo, mut hi) = ends(form.main);
        if let Some(fine) = form.fine {
            let (a, b) = ends(fine);
            (lo, hi) = (lo + a, hi + b);
        }
        if form.sign.is_some() {
            let m = lo.abs().max(hi.abs());
            (lo, hi) = (-m, m);
        }
        let margin = Self::STEPS * form.quantum();
        Self {
            range: (lo, hi),
            below: if lo < 0.0 {
                lo + margin
            } else {
                f64::NEG_INFINITY
            },
            above: if hi > 0.0 { hi - margin } else { f64::INFINITY },
        }
    }

    /// Whether `reading` (in the form's unit) is at an end of the range.
    #[inline]
    pub fn is_saturated(&self, reading: f64) -> bool {
        reading <= self.below || reading >= self.above
    }
}

/// `MESSAGE.SIGNAL` of a handle, for messages naming it.
pub fn signal_path(db: &Database, h: SignalHandle) -> String {
    let m = &db.messages()[h.message_index()];
    format!("{}.{}", m.name(), m.signals()[h.signal_index()].name())
}

/// A direction source resolved: its signal and the raw values of reversing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DirectionSignal {
    /// The direction or gear signal.
    pub handle: SignalHandle,
    /// Index of its message in the database.
    pub message_index: usize,
    /// Bit `v` set: raw value `v` means reversing (values 0..=63).
    pub reverse_mask: u64,
    /// A raw value that means driving forward, for encoders.
    pub forward_raw: u64,
}

impl DirectionSignal {
    /// Whether `raw` means reversing.
    #[inline]
    pub fn is_reverse(&self, raw: u64) -> bool {
        raw < 64 && self.reverse_mask & (1 << raw) != 0
    }

    /// The raw value of reversing (the first listed), for encoders.
    pub fn reverse_raw(&self) -> u64 {
        u64::from(self.reverse_mask.trailing_zeros())
    }
}

/// What a form refuses: the key, what was expected, what the file says.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FormError {
    /// Dotted key, e.g. `signals.steering.sign`.
    pub key: String,
    /// What would have been accepted.
    pub expected: String,
    /// What the file says.
    pub got: String,
}

fn form_err(key: &str, expected: impl Into<String>, got: impl fmt::Display) -> FormError {
    FormError {
        key: key.to_owned(),
        expected: expected.into(),
        got: got.to_string(),
    }
}

/// A quantity resolved: its form, its message, its unit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Resolved {
    /// The signals.
    pub form: SignalForm,
    /// Index of their message in the database.
    pub message_index: usize,
    /// The unit (the override, else the DBC's), when recognised.
    pub unit: Option<Unit>,
}

fn handle(db: &Database, key: &str, path: &str) -> Result<SignalHandle, FormError> {
    db.signal(path).map_err(|e| {
        form_err(
            key,
            format!("\"MESSAGE.SIGNAL\" present in {}", db.source_name()),
            format!("{path:?} ({e})"),
        )
    })
}

fn unit_text(db: &Database, h: SignalHandle) -> String {
    db.messages()[h.message_index()].signals()[h.signal_index()]
        .unit()
        .to_owned()
}

/// Resolves `raw` at `key` against `db`: every signal present, all in one
/// message, a sign only beside a magnitude, a sum of exactly two, the unit
/// recognised and of `quantity` (when given).
///
/// # Errors
/// [`FormError`] naming the key (`signals.steering.sign`, ...), what was
/// expected and what the file says.
pub fn resolve(
    db: &Database,
    key: &str,
    raw: &RawSignal,
    quantity: Option<Quantity>,
) -> Result<Resolved, FormError> {
    let (main, fine) = match (&raw.signal, &raw.sum) {
        (Some(path), None) => (handle(db, key, path)?, None),
        (None, Some(parts)) => match parts.as_slice() {
            [a, b] => {
                let k = format!("{key}.sum");
                let (a, b) = (handle(db, &k, a)?, handle(db, &k, b)?);
                (a, Some(b))
            }
            _ => {
                return Err(form_err(
                    &format!("{key}.sum"),
                    "two signals, [\"MESSAGE.COARSE\", \"MESSAGE.FINE\"]",
                    format!("{} signals", parts.len()),
                ));
            }
        },
        (Some(_), Some(_)) => {
            return Err(form_err(key, "either signal or sum, not both", "both"));
        }
        (None, None) => {
            return Err(form_err(
                key,
                "\"MESSAGE.SIGNAL\" or a table with signal = \"MESSAGE.SIGNAL\" or sum = [..]",
                "a table without either",
            ));
        }
    };
    let message_index = main.message_index();
    let same_message = |k: &str, h: SignalHandle, path: &str| {
        if h.message_index() == message_index {
            Ok(())
        } else {
            Err(form_err(
                k,
                format!(
                    "a signal of the same message as {key} ({})",
                    db.messages()[message_index].name()
                ),
                path,
            ))
        }
    };
    if let (Some(f), Some(parts)) = (fine, &raw.sum) {
        same_message(&format!("{key}.sum"), f, &parts[1])?;
    }
    let sign = match (&raw.sign, raw.negative_when) {
        (None, None) => None,
        (None, Some(v)) => {
            return Err(form_err(
                &format!("{key}.negative_when"),
                format!("{key}.sign beside it"),
                format!("negative_when = {v} without a sign signal"),
            ));
        }
        (Some(path), negative_when) => {
            let k = format!("{key}.sign");
            let h = handle(db, &k, path)?;
            same_message(&k, h, path)?;
            let negative_raw = negative_when.unwrap_or(1);
            let max = if h.size() >= 64 {
                u64::MAX
            } else {
                (1u64 << h.size()) - 1
            };
            if negative_raw > max {
                return Err(form_err(
                    &format!("{key}.negative_when"),
                    format!(
                        "a raw value of the {}-bit sign signal (0..={max})",
                        h.size()
                    ),
                    negative_raw,
                ));
            }
            Some(SignBit {
                handle: h,
                negative_raw,
            })
        }
    };
    let unit = check_unit(db, key, raw, quantity, main, fine)?;
    Ok(Resolved {
        form: SignalForm { main, fine, sign },
        message_index,
        unit,
    })
}

/// The unit of a quantity (the override, else the DBC's), checked to be
/// of `quantity` when given, a sum's parts in one unit.
fn check_unit(
    db: &Database,
    key: &str,
    raw: &RawSignal,
    quantity: Option<Quantity>,
    main: SignalHandle,
    fine: Option<SignalHandle>,
) -> Result<Option<Unit>, FormError> {
    let (unit, unit_key, spelled) = if let Some(u) = &raw.unit {
        (Unit::parse(u), format!("{key}.unit"), u.clone())
    } else {
        let text = unit_text(db, main);
        (Unit::parse(&text), key.to_owned(), text)
    };
    if let Some(q) = quantity {
        match unit {
            Some(u) if u.quantity() == q => {}
            Some(u) => {
                return Err(form_err(
                    &unit_key,
                    format!("{q}"),
                    format!("{} with unit {spelled:?} ({u:?})", raw.name()),
                ));
            }
            None if raw.unit.is_some() => {
                return Err(form_err(
                    &unit_key,
                    format!("{q}, spelt as canodom knows it"),
                    format!("{spelled:?}"),
                ));
            }
            None => {
                return Err(form_err(
                    &unit_key,
                    format!("{q} as the DBC unit, or `unit = \"...\"` in {key} to say it"),
                    format!("{} with unit {spelled:?}", raw.name()),
                ));
            }
        }
        if raw.unit.is_none()
            && let Some(f) = fine
        {
            let fine_text = unit_text(db, f);
            if Unit::parse(&fine_text) != unit {
                return Err(form_err(
                    &format!("{key}.sum"),
                    format!("a fine part in the coarse part's unit ({spelled})"),
                    format!("unit {fine_text:?}"),
                ));
            }
        }
    }
    Ok(unit)
}

/// Resolves `[signals] direction`: its signal, and the second one when
/// `signal` names two (each read with the same `reverse` names or values).
///
/// # Errors
/// [`FormError`] naming `signals.direction...`: a signal the DBC lacks, a
/// reverse value its table lacks, more than two signals, two in one message.
pub fn resolve_direction(
    db: &Database,
    raw: &RawDirection,
) -> Result<(DirectionSignal, Option<DirectionSignal>), FormError> {
    let key = "signals.direction.signal";
    match raw.signal.paths() {
        [one] => Ok((resolve_gear(db, one, &raw.reverse)?, None)),
        [a, b] => {
            let (a_sig, b_sig) = (
                resolve_gear(db, a, &raw.reverse)?,
                resolve_gear(db, b, &raw.reverse)?,
            );
            if a_sig.message_index == b_sig.message_index {
                return Err(form_err(
                    key,
                    "two signals of two messages (one per gearbox)",
                    format!("{a:?} and {b:?}, one message"),
                ));
            }
            Ok((a_sig, Some(b_sig)))
        }
        other => Err(form_err(
            key,
            "\"MESSAGE.SIGNAL\", or two of them in a list (one per gearbox)",
            format!("{} signals", other.len()),
        )),
    }
}

/// One direction or gear signal of `[signals] direction`.
fn resolve_gear(
    db: &Database,
    path: &str,
    reverse: &[RawValue],
) -> Result<DirectionSignal, FormError> {
    let key = "signals.direction";
    let h = handle(db, &format!("{key}.signal"), path)?;
    let signal = &db.messages()[h.message_index()].signals()[h.signal_index()];
    let table = signal.value_descriptions();
    if reverse.is_empty() {
        return Err(form_err(
            &format!("{key}.reverse"),
            "the values that mean reversing, raw (1) or named (\"R\")",
            "[]",
        ));
    }
    let mut mask = 0u64;
    for v in reverse {
        let value = match v {
            RawValue::Raw(r) => *r,
            RawValue::Name(name) => table
                .iter()
                .find(|(_, n)| n.eq_ignore_ascii_case(name))
                .and_then(|(r, _)| u64::try_from(*r).ok())
                .ok_or_else(|| {
                    let names: Vec<&str> = table.iter().map(|(_, n)| n.as_str()).collect();
                    form_err(
                        &format!("{key}.reverse"),
                        if names.is_empty() {
                            format!("raw values: {path} has no value table")
                        } else {
                            format!("a raw value or one of {names:?}")
                        },
                        format!("{name:?}"),
                    )
                })?,
        };
        if value >= 64 {
            return Err(form_err(
                &format!("{key}.reverse"),
                "raw values 0..=63",
                value,
            ));
        }
        mask |= 1 << value;
    }
    let forward_named = table
        .iter()
        .find(|(_, n)| {
            let n = n.to_ascii_uppercase();
            n == "D" || n == "DRIVE" || n.starts_with("FORWARD") || n == "VORWAERTS"
        })
        .and_then(|(r, _)| u64::try_from(*r).ok())
        .filter(|&r| r >= 64 || mask & (1 << r) == 0);
    let forward_raw =
        forward_named.unwrap_or_else(|| (0..64).find(|r| mask & (1 << r) == 0).unwrap_or(64));
    Ok(DirectionSignal {
        handle: h,
        message_index: h.message_index(),
        reverse_mask: mask,
        forward_raw,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opendbc_unit_spellings_are_recognised() {
        for (text, unit) in [
            ("Unit_KiloMeterPerHour", Unit::KilometresPerHour),
            ("km/h", Unit::KilometresPerHour),
            ("kph", Unit::KilometresPerHour),
            ("KPH", Unit::KilometresPerHour),
            ("m/s", Unit::MetresPerSecond),
            ("mph", Unit::MilesPerHour),
            ("Unit_DegreOfArc", Unit::Degrees),
            ("deg", Unit::Degrees),
            ("degrees", Unit::Degrees),
            ("°", Unit::Degrees),
            ("rad", Unit::Radians),
            ("Unit_DegreOfArcPerSecon", Unit::DegreesPerSecond),
            ("deg/s", Unit::DegreesPerSecond),
            ("°/s", Unit::DegreesPerSecond),
            ("deg/sec", Unit::DegreesPerSecond),
            ("rad/s", Unit::RadiansPerSecond),
            ("km / h", Unit::KilometresPerHour),
            ("Kph", Unit::KilometresPerHour),
            ("°Grad/s", Unit::DegreesPerSecond),
            ("°Grad", Unit::Degrees),
            ("Unit_DegreePerSecond", Unit::DegreesPerSecond),
            ("Unit_MeterPerSecond", Unit::MetresPerSecond),
            ("radians/second", Unit::RadiansPerSecond),
        ] {
            assert_eq!(Unit::parse(text), Some(unit), "{text}");
        }
        for text in ["", "Unit_MeterPerSeconSquar", "m/s^2", "g", "Nm", "%"] {
            assert_eq!(Unit::parse(text), None, "{text}");
        }
        assert!((Unit::MilesPerHour.si_per_unit() * 3600.0 - 1609.344).abs() < 1e-9);
    }

    const DBC: &str = r#"VERSION ""
BO_ 134 LWI_01: 8 X
 SG_ LWI_Lenkradwinkel : 16|13@1+ (0.1,0) [0|800] "Unit_DegreOfArc" X
 SG_ LWI_VZ_Lenkradwinkel : 29|1@1+ (1,0) [0|1] "" X
 SG_ COARSE : 32|8@1- (1.5,0) [-192|190.5] "deg" X
 SG_ FINE : 40|4@1- (0.1,0) [-0.8|0.7] "deg" X
BO_ 173 Getriebe_11: 8 X
 SG_ GE_Fahrstufe : 40|4@1+ (1,0) [0|15] "" X
 SG_ SPEED : 0|16@1+ (0.01,0) [0|600] "Unit_KiloMeterPerHour" X
VAL_ 173 GE_Fahrstufe 5 "P" 6 "R" 7 "N" 8 "D" ;
"#;

    fn db() -> Database {
        Database::parse(DBC, "t.dbc").unwrap()
    }

    fn table(toml_text: &str) -> RawSignal {
        #[derive(Deserialize)]
        struct T {
            s: RawSignal,
        }
        toml::from_str::<T>(toml_text).unwrap().s
    }

    #[test]
    fn magnitude_and_sign_decode_and_encode_either_polarity() {
        let db = db();
        for (negative_when, extra) in [(1u64, ""), (0, ", negative_when = 0")] {
            let raw = table(&format!(
                "s = {{ signal = \"LWI_01.LWI_Lenkradwinkel\", sign = \"LWI_01.LWI_VZ_Lenkradwinkel\"{extra} }}"
            ));
            let r = resolve(&db, "signals.steering", &raw, Some(Quantity::Angle)).unwrap();
            assert_eq!(r.unit, Some(Unit::Degrees));
            assert_eq!(r.form.sign.unwrap().negative_raw, negative_when);
            for v in [-123.4, -0.1, 0.0, 0.1, 456.7] {
                let mut data = [0u8; 8];
                assert!(r.form.encode(v, &mut data));
                let sign_raw = r.form.sign.unwrap().handle.raw(&data).unwrap();
                assert_eq!(sign_raw == negative_when, v < 0.0, "{v}");
                assert!((r.form.decode(&data).unwrap() - v).abs() < 1e-9, "{v}");
            }
        }
    }

    #[test]
    fn sum_adds_coarse_and_fine() {
        let db = db();
        let raw = table("s = { sum = [\"LWI_01.COARSE\", \"LWI_01.FINE\"] }");
        let r = resolve(&db, "signals.steering", &raw, Some(Quantity::Angle)).unwrap();
        assert!((r.form.quantum() - 0.1).abs() < 1e-12);
        for v in [-100.3, -0.7, 0.0, 3.1, 150.2] {
            let mut data = [0u8; 8];
            assert!(r.form.encode(v, &mut data));
            assert!((r.form.decode(&data).unwrap() - v).abs() < 1e-9, "{v}");
        }
    }

    #[test]
    fn bad_forms_name_the_key() {
        let db = db();
        let e = |toml_text: &str, q| {
            resolve(&db, "signals.steering", &table(toml_text), q).unwrap_err()
        };
        let x = e(
            "s = { signal = \"LWI_01.LWI_Lenkradwinkel\", sign = \"Getriebe_11.GE_Fahrstufe\" }",
            None,
        );
        assert_eq!(x.key, "signals.steering.sign");
        assert!(x.expected.contains("LWI_01"), "{x:?}");
        let x = e(
            "s = { signal = \"LWI_01.LWI_Lenkradwinkel\", negative_when = 0 }",
            None,
        );
        assert_eq!(x.key, "signals.steering.negative_when");
        let x = e("s = { sum = [\"LWI_01.COARSE\"] }", None);
        assert_eq!(x.key, "signals.steering.sum");
        let x = e(
            "s = { signal = \"LWI_01.LWI_Lenkradwinkel\", sign = \"LWI_01.LWI_VZ_Lenkradwinkel\", negative_when = 2 }",
            None,
        );
        assert!(x.expected.contains("0..=1"), "{x:?}");
        let x = e(
            "s = { signal = \"LWI_01.LWI_Lenkradwinkel\", unit = \"furlong\" }",
            Some(Quantity::Angle),
        );
        assert_eq!(x.key, "signals.steering.unit");
        let x = e("s = \"Getriebe_11.SPEED\"", Some(Quantity::Angle));
        assert!(
            x.expected.contains("angle") && x.got.contains("Unit_KiloMeterPerHour"),
            "{x:?}"
        );
        let x = e("s = \"Getriebe_11.GE_Fahrstufe\"", Some(Quantity::Angle));
        assert!(x.expected.contains("unit = "), "{x:?}");
        // An override fixes a missing unit.
        let raw = table("s = { signal = \"Getriebe_11.GE_Fahrstufe\", unit = \"deg\" }");
        assert!(resolve(&db, "k", &raw, Some(Quantity::Angle)).is_ok());
        // Unknown keys are refused by name.
        let err = toml::from_str::<toml::Value>("s = { signal = \"a.b\", sigh = \"x\" }")
            .ok()
            .and_then(|_| {
                #[derive(Deserialize, Debug)]
                #[allow(dead_code)]
                struct T {
                    s: RawSignal,
                }
                toml::from_str::<T>("s = { signal = \"a.b\", sigh = \"x\" }").err()
            })
            .unwrap()
            .to_string();
        assert!(err.contains("sigh"), "{err}");
    }

    #[test]
    fn direction_by_name_or_raw() {
        let db = db();
        let (d, _) = resolve_direction(
            &db,
            &RawDirection {
                signal: "Getriebe_11.GE_Fahrstufe".into(),
                reverse: vec![RawValue::Name("r".into())],
            },
        )
        .unwrap();
        assert!(d.is_reverse(6) && !d.is_reverse(8) && !d.is_reverse(100));
        assert_eq!((d.reverse_raw(), d.forward_raw), (6, 8));
        let e = resolve_direction(
            &db,
            &RawDirection {
                signal: "Getriebe_11.GE_Fahrstufe".into(),
                reverse: vec![RawValue::Name("Rueckwaerts".into())],
            },
        )
        .unwrap_err();
        assert!(
            e.expected.contains("\"R\"") && e.key == "signals.direction.reverse",
            "{e:?}"
        );
        let (d, _) = resolve_direction(
            &db,
            &RawDirection {
                signal: "LWI_01.LWI_VZ_Lenkradwinkel".into(),
                reverse: vec![RawValue::Raw(1)],
            },
        )
        .unwrap();
        assert_eq!((d.reverse_raw(), d.forward_raw), (1, 0));
    }
}
