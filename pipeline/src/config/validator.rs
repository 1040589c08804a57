//! The validator: the file under check, and the small checks every
//! section shares, each naming the file and the dotted key in its error so
//! that a refusal always says where and what was expected.

use super::{ConfigError, InputSignal, STATE_DIRECTORY_ENV};
use crate::signal_forms::{FormError, Quantity, RawSignal, SignalForm, Unit};
use canodom_dbc::Database;
use std::ffi::OsString;
use std::path::Path;

pub(super) struct Validator<'a> {
    pub(super) file: &'a Path,
    /// `$STATE_DIRECTORY` as the process found it, for [`default_param_file`].
    pub(super) state_directory: Option<OsString>,
}

impl<'a> Validator<'a> {
    pub(super) fn new(file: &'a Path) -> Self {
        Self {
            file,
            state_directory: std::env::var_os(STATE_DIRECTORY_ENV),
        }
    }
}

impl Validator<'_> {
    pub(super) fn err(
        &self,
        key: &str,
        expected: &str,
        got: impl std::fmt::Display,
    ) -> ConfigError {
        ConfigError::Invalid {
            file: self.file.to_owned(),
            key: key.to_owned(),
            expected: expected.to_owned(),
            got: got.to_string(),
        }
    }

    pub(super) fn positive(&self, key: &str, v: f64) -> Result<f64, ConfigError> {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(key, "a finite number > 0", v))
        }
    }

    pub(super) fn non_negative(&self, key: &str, v: f64) -> Result<f64, ConfigError> {
        if v.is_finite() && v >= 0.0 {
            Ok(v)
        } else {
            Err(self.err(key, "a finite number >= 0", v))
        }
    }

    pub(super) fn signal(
        &self,
        db: &Database,
        key: &str,
        path: &str,
    ) -> Result<InputSignal, ConfigError> {
        let handle = db.signal(path).map_err(|e| {
            self.err(
                key,
                &format!("\"MESSAGE.SIGNAL\" present in {}", db.source_name()),
                format!("{path:?} ({e})"),
            )
        })?;
        Ok(InputSignal {
            handle,
            message_index: handle.message_index(),
            form: SignalForm::plain(handle),
        })
    }

    /// A quantity of `[signals]` in any form ([`crate::signal_forms`]),
    /// its unit of `quantity` when given.
    pub(super) fn quantity(
        &self,
        db: &Database,
        key: &str,
        raw: &RawSignal,
        quantity: Option<Quantity>,
    ) -> Result<(InputSignal, Option<Unit>), ConfigError> {
        let r = crate::signal_forms::resolve(db, key, raw, quantity).map_err(|e| self.form(e))?;
        Ok((
            InputSignal {
                handle: r.form.main,
                message_index: r.message_index,
                form: r.form,
            },
            r.unit,
        ))
    }

    pub(super) fn form(&self, e: FormError) -> ConfigError {
        self.err(&e.key, &e.expected, e.got)
    }
}
