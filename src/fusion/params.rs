//! Engine parameters: each engine declares [`ParamSpec`]s (name, kind,
//! default, range, unit, meaning); [`Params`] holds a validated, complete
//! set of values resolved against those specs.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// The type, default and allowed values of one parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ParamKind {
    /// A real number in `[min, max]`.
    Real { default: f64, min: f64, max: f64 },
    /// A whole number in `[min, max]`.
    Integer { default: i64, min: i64, max: i64 },
    /// `true` or `false`.
    Bool { default: bool },
    /// One of a fixed set of words.
    Choice {
        default: &'static str,
        options: &'static [&'static str],
    },
}

/// One parameter an engine accepts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamSpec {
    pub name: &'static str,
    pub kind: ParamKind,
    /// Unit of the value, empty when it has none.
    pub unit: &'static str,
    /// What the parameter does, one sentence.
    pub doc: &'static str,
}

impl ParamSpec {
    /// The default value.
    pub fn default_value(&self) -> ParamValue {
        match self.kind {
            ParamKind::Real { default, .. } => ParamValue::Number(default),
            ParamKind::Integer { default, .. } => ParamValue::Number(default as f64),
            ParamKind::Bool { default } => ParamValue::Bool(default),
            ParamKind::Choice { default, .. } => ParamValue::Text(default.to_string()),
        }
    }

    /// A human description of the allowed values, e.g. `0 to 1`.
    pub fn range_text(&self) -> String {
        match self.kind {
            ParamKind::Real { min, max, .. } => format!("{min} to {max}"),
            ParamKind::Integer { min, max, .. } => format!("{min} to {max} (whole)"),
            ParamKind::Bool { .. } => "true or false".to_string(),
            ParamKind::Choice { options, .. } => options.join(" | "),
        }
    }

    /// Parses a value given as text (command line `--param name=value`).
    pub fn parse_text(&self, text: &str) -> Result<ParamValue, ParamError> {
        let text = text.trim();
        let value = match self.kind {
            ParamKind::Real { .. } | ParamKind::Integer { .. } => text
                .parse::<f64>()
                .map(ParamValue::Number)
                .map_err(|_| self.invalid(text))?,
            ParamKind::Bool { .. } => match text {
                "true" | "1" | "on" | "yes" => ParamValue::Bool(true),
                "false" | "0" | "off" | "no" => ParamValue::Bool(false),
                _ => return Err(self.invalid(text)),
            },
            ParamKind::Choice { .. } => ParamValue::Text(text.to_string()),
        };
        self.check(value)
    }

    /// Checks a value against the kind and range.
    pub fn check(&self, value: ParamValue) -> Result<ParamValue, ParamError> {
        match (self.kind, &value) {
            (ParamKind::Real { min, max, .. }, ParamValue::Number(x)) => {
                if !x.is_finite() || *x < min || *x > max {
                    return Err(self.out_of_range(&value));
                }
            }
            (ParamKind::Integer { min, max, .. }, ParamValue::Number(x)) => {
                if x.fract() != 0.0 {
                    return Err(self.invalid(&value.to_string()));
                }
                if *x < min as f64 || *x > max as f64 {
                    return Err(self.out_of_range(&value));
                }
            }
            (ParamKind::Bool { .. }, ParamValue::Bool(_)) => {}
            (ParamKind::Choice { options, .. }, ParamValue::Text(word)) => {
                if !options.contains(&word.as_str()) {
                    return Err(self.out_of_range(&value));
                }
            }
            _ => return Err(self.invalid(&value.to_string())),
        }
        Ok(value)
    }

    fn invalid(&self, value: &str) -> ParamError {
        ParamError::Invalid {
            name: self.name.to_string(),
            value: value.to_string(),
            expected: self.range_text(),
        }
    }

    fn out_of_range(&self, value: &ParamValue) -> ParamError {
        ParamError::OutOfRange {
            name: self.name.to_string(),
            value: value.to_string(),
            allowed: self.range_text(),
        }
    }
}

/// A real parameter spec (for engines' `PARAMS` tables).
pub const fn real(
    name: &'static str,
    default: f64,
    min: f64,
    max: f64,
    unit: &'static str,
    doc: &'static str,
) -> ParamSpec {
    ParamSpec {
        name,
        kind: ParamKind::Real { default, min, max },
        unit,
        doc,
    }
}

/// A whole-number parameter spec without a unit.
pub const fn integer(
    name: &'static str,
    default: i64,
    min: i64,
    max: i64,
    doc: &'static str,
) -> ParamSpec {
    ParamSpec {
        name,
        kind: ParamKind::Integer { default, min, max },
        unit: "",
        doc,
    }
}

/// A choice parameter spec.
pub const fn choice(
    name: &'static str,
    default: &'static str,
    options: &'static [&'static str],
    doc: &'static str,
) -> ParamSpec {
    ParamSpec {
        name,
        kind: ParamKind::Choice { default, options },
        unit: "",
        doc,
    }
}

/// A true/false parameter spec.
pub const fn flag(name: &'static str, default: bool, doc: &'static str) -> ParamSpec {
    ParamSpec {
        name,
        kind: ParamKind::Bool { default },
        unit: "",
        doc,
    }
}

/// A parameter value as it appears in configuration files and JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(untagged)]
pub enum ParamValue {
    Bool(bool),
    Number(f64),
    Text(String),
}

impl std::fmt::Display for ParamValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ParamValue::Bool(b) => write!(f, "{b}"),
            ParamValue::Number(x) => write!(f, "{x}"),
            ParamValue::Text(s) => write!(f, "{s}"),
        }
    }
}

/// Why a set of parameters was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamError {
    #[error("unknown parameter `{name}` (known: {known})")]
    Unknown { name: String, known: String },
    #[error("parameter `{name}` = `{value}` is not valid (expected {expected})")]
    Invalid {
        name: String,
        value: String,
        expected: String,
    },
    #[error("parameter `{name}` = {value} is out of range (allowed: {allowed})")]
    OutOfRange {
        name: String,
        value: String,
        allowed: String,
    },
    #[error("parameters do not fit together: {0}")]
    Inconsistent(String),
    #[error("parameter `{name}` was retired: {reason}")]
    Retired { name: String, reason: String },
    #[error("malformed parameter `{0}`: expected name=value")]
    Malformed(String),
}

/// A parameter an earlier release had and this one does not, with why.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Retired {
    pub name: &'static str,
    pub reason: &'static str,
}

/// Refuses `name` if it is retired, saying why.
pub fn check_retired(retired: &[Retired], name: &str) -> Result<(), ParamError> {
    match retired.iter().find(|r| r.name == name) {
        Some(r) => Err(ParamError::Retired {
            name: r.name.to_string(),
            reason: r.reason.to_string(),
        }),
        None => Ok(()),
    }
}

/// A complete, validated set of parameter values for one engine.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Params {
    values: BTreeMap<String, ParamValue>,
}

impl Params {
    /// Every spec at its default.
    pub fn defaults(specs: &[ParamSpec]) -> Params {
        Params {
            values: specs
                .iter()
                .map(|s| (s.name.to_string(), s.default_value()))
                .collect(),
        }
    }

    /// Defaults overridden by `overrides`; unknown names and bad values are
    /// refused with an error naming them.
    pub fn resolve(
        specs: &[ParamSpec],
        overrides: impl IntoIterator<Item = (String, ParamValue)>,
    ) -> Result<Params, ParamError> {
        let mut params = Params::defaults(specs);
        for (name, value) in overrides {
            let spec = find(specs, &name)?;
            let value = spec.check(value)?;
            params.values.insert(name, value);
        }
        Ok(params)
    }

    /// Values stored by an earlier release made current: retired names
    /// are dropped, new parameters take their defaults, the rest is
    /// checked as always.
    pub fn upgraded(&self, specs: &[ParamSpec], retired: &[Retired]) -> Result<Params, ParamError> {
        Params::resolve(
            specs,
            self.values
                .iter()
                .filter(|(name, _)| check_retired(retired, name).is_ok())
                .map(|(k, v)| (k.clone(), v.clone())),
        )
    }

    /// The same values checked again against `specs` (a restored
    /// snapshot's parameters are not trusted).
    pub fn revalidated(&self, specs: &[ParamSpec]) -> Result<Params, ParamError> {
        self.with_overrides(specs, [])
    }

    /// These values with `overrides` on top, resolved against `specs`.
    pub fn with_overrides(
        &self,
        specs: &[ParamSpec],
        overrides: impl IntoIterator<Item = (String, ParamValue)>,
    ) -> Result<Params, ParamError> {
        Params::resolve(
            specs,
            self.values
                .iter()
                .map(|(k, v)| (k.clone(), v.clone()))
                .chain(overrides),
        )
    }

    /// Like [`Params::resolve`], from `name=value` words.
    pub fn from_assignments<'a>(
        specs: &[ParamSpec],
        assignments: impl IntoIterator<Item = &'a str>,
    ) -> Result<Params, ParamError> {
        let mut overrides = Vec::new();
        for assignment in assignments {
            let (name, text) = assignment
                .split_once('=')
                .ok_or_else(|| ParamError::Malformed(assignment.to_string()))?;
            let name = name.trim();
            let value = find(specs, name)?.parse_text(text)?;
            overrides.push((name.to_string(), value));
        }
        Params::resolve(specs, overrides)
    }

    /// Values a typed struct holds (each already checked when it was read).
    pub fn from_checked<const N: usize>(values: [(&'static str, ParamValue); N]) -> Params {
        Params {
            values: values
                .into_iter()
                .map(|(name, value)| (name.to_string(), value))
                .collect(),
        }
    }

    /// All values by name.
    pub fn values(&self) -> &BTreeMap<String, ParamValue> {
        &self.values
    }

    /// A real-valued (or integer) parameter.
    pub fn real(&self, name: &'static str) -> Result<f64, ParamError> {
        match self.values.get(name) {
            Some(ParamValue::Number(x)) => Ok(*x),
            other => Err(self.missing(name, other)),
        }
    }

    /// A whole-number parameter.
    pub fn integer(&self, name: &'static str) -> Result<i64, ParamError> {
        self.real(name).map(|x| x as i64)
    }

    /// A boolean parameter.
    pub fn flag(&self, name: &'static str) -> Result<bool, ParamError> {
        match self.values.get(name) {
            Some(ParamValue::Bool(b)) => Ok(*b),
            other => Err(self.missing(name, other)),
        }
    }

    /// A choice parameter.
    pub fn choice(&self, name: &'static str) -> Result<&str, ParamError> {
        match self.values.get(name) {
            Some(ParamValue::Text(s)) => Ok(s),
            other => Err(self.missing(name, other)),
        }
    }

    fn missing(&self, name: &str, found: Option<&ParamValue>) -> ParamError {
        ParamError::Invalid {
            name: name.to_string(),
            value: found.map(|v| v.to_string()).unwrap_or_default(),
            expected: "a value of the declared kind".to_string(),
        }
    }
}

/// A parameter field of a typed parameter struct: how its value is read
/// from, and written back to, a validated [`Params`].
pub trait ParamField: Sized {
    /// The value named `name` (already validated against its spec).
    fn read(params: &Params, name: &'static str) -> Result<Self, ParamError>;
    /// The value as it appears in declarations.
    fn value(&self) -> ParamValue;
}

impl ParamField for f64 {
    fn read(params: &Params, name: &'static str) -> Result<f64, ParamError> {
        params.real(name)
    }
    fn value(&self) -> ParamValue {
        ParamValue::Number(*self)
    }
}

impl ParamField for usize {
    fn read(params: &Params, name: &'static str) -> Result<usize, ParamError> {
        let x = params.integer(name)?;
        usize::try_from(x).map_err(|_| ParamError::Invalid {
            name: name.to_string(),
            value: x.to_string(),
            expected: "a whole number of at least 0".to_string(),
        })
    }
    fn value(&self) -> ParamValue {
        ParamValue::Number(*self as f64)
    }
}

impl ParamField for bool {
    fn read(params: &Params, name: &'static str) -> Result<bool, ParamError> {
        params.flag(name)
    }
    fn value(&self) -> ParamValue {
        ParamValue::Bool(*self)
    }
}

/// A typed view of an engine's parameters, generated with its spec table
/// by [`param_table!`]: the engine reads fields, never names.
pub trait TypedParams: Sized {
    /// The spec table the struct is generated from.
    const SPECS: &'static [ParamSpec];
    /// The typed values of validated parameters.
    fn from_params(params: &Params) -> Result<Self, ParamError>;
    /// The values back as parameters (round trip of [`TypedParams::from_params`]).
    fn to_params(&self) -> Params;
}

/// The typed struct of a choice parameter's words: an enum with one
/// variant per word, parsed once, never defaulted.
///
/// ```text
/// choice_enum! {
///     /// Where the noise comes from.
///     pub enum NoiseMode { Adaptive = "adaptive", Fixed = "fixed" }
/// }
/// ```
macro_rules! choice_enum {
    (
        $(#[$meta:meta])*
        $vis:vis enum $Name:ident {
            $( $(#[$vmeta:meta])* $Variant:ident = $word:literal ),+ $(,)?
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
        $vis enum $Name {
            $( $(#[$vmeta])* #[serde(rename = $word)] $Variant ),+
        }

        impl $Name {
            /// Every word, in declaration order.
            pub const WORDS: &'static [&'static str] = &[$($word),+];

            /// The protocol word.
            pub const fn as_str(self) -> &'static str {
                match self {
                    $( $Name::$Variant => $word ),+
                }
            }

            /// The value a word names, if it names one.
            pub fn from_name(word: &str) -> Option<$Name> {
                match word {
                    $( $word => Some($Name::$Variant), )+
                    _ => None,
                }
            }
        }

        // Its schema (the OpenAPI document) lists its words.
        impl utoipa::PartialSchema for $Name {
            fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
                utoipa::openapi::schema::ObjectBuilder::new()
                    .schema_type(utoipa::openapi::schema::Type::String)
                    .enum_values(Some($Name::WORDS.iter().copied()))
                    .into()
            }
        }

        impl utoipa::ToSchema for $Name {
            fn name() -> std::borrow::Cow<'static, str> {
                std::borrow::Cow::Borrowed(stringify!($Name))
            }
        }

        impl $crate::fusion::params::ParamField for $Name {
            fn read(
                params: &$crate::fusion::params::Params,
                name: &'static str,
            ) -> Result<$Name, $crate::fusion::params::ParamError> {
                let word = params.choice(name)?;
                $Name::from_name(word).ok_or_else(|| $crate::fusion::params::ParamError::Invalid {
                    name: name.to_string(),
                    value: word.to_string(),
                    expected: $Name::WORDS.join(" | "),
                })
            }
            fn value(&self) -> $crate::fusion::params::ParamValue {
                $crate::fusion::params::ParamValue::Text(self.as_str().to_string())
            }
        }
    };
}
pub(crate) use choice_enum;

/// An engine's parameter table and its typed struct, from one list:
/// `name: type = kind(default, range…, unit, doc)` with kind `real`
/// (`f64`: default, min, max, unit, doc), `integer` (`usize`: default,
/// min, max, doc), `flag` (`bool`: default, doc) or `choice` (a
/// [`choice_enum!`] type: default variant, doc).
macro_rules! param_table {
    (
        $(#[$meta:meta])*
        $vis:vis struct $Name:ident in $TABLE:ident {
            $( $field:ident : $ty:ty = $kind:ident ( $($arg:expr),* $(,)? ) ),* $(,)?
        }
    ) => {
        /// The parameter table: name, kind, default, range, unit, meaning.
        $vis const $TABLE: &[$crate::fusion::params::ParamSpec] = &[
            $( $crate::fusion::params::param_table!(@spec $field, $ty, $kind($($arg),*)) ),*
        ];

        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq)]
        $vis struct $Name {
            $( pub $field: $ty ),*
        }

        impl $crate::fusion::params::TypedParams for $Name {
            const SPECS: &'static [$crate::fusion::params::ParamSpec] = $TABLE;

            fn from_params(
                params: &$crate::fusion::params::Params,
            ) -> Result<$Name, $crate::fusion::params::ParamError> {
                Ok($Name {
                    $( $field: <$ty as $crate::fusion::params::ParamField>::read(
                        params,
                        stringify!($field),
                    )? ),*
                })
            }

            fn to_params(&self) -> $crate::fusion::params::Params {
                $crate::fusion::params::Params::from_checked([
                    $( (
                        stringify!($field),
                        $crate::fusion::params::ParamField::value(&self.$field),
                    ) ),*
                ])
            }
        }
    };
    (@spec $field:ident, $ty:ty, real($default:expr, $min:expr, $max:expr, $unit:expr, $doc:expr)) => {
        $crate::fusion::params::real(stringify!($field), $default, $min, $max, $unit, $doc)
    };
    (@spec $field:ident, $ty:ty, integer($default:expr, $min:expr, $max:expr, $doc:expr)) => {
        $crate::fusion::params::integer(stringify!($field), $default, $min, $max, $doc)
    };
    (@spec $field:ident, $ty:ty, flag($default:expr, $doc:expr)) => {
        $crate::fusion::params::flag(stringify!($field), $default, $doc)
    };
    (@spec $field:ident, $ty:ty, choice($default:expr, $doc:expr)) => {
        $crate::fusion::params::choice(stringify!($field), <$ty>::as_str($default), <$ty>::WORDS, $doc)
    };
}
pub(crate) use param_table;

fn find<'a>(specs: &'a [ParamSpec], name: &str) -> Result<&'a ParamSpec, ParamError> {
    specs
        .iter()
        .find(|s| s.name == name)
        .ok_or_else(|| ParamError::Unknown {
            name: name.to_string(),
            known: specs.iter().map(|s| s.name).collect::<Vec<_>>().join(", "),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SPECS: &[ParamSpec] = &[
        ParamSpec {
            name: "gain",
            kind: ParamKind::Real {
                default: 0.02,
                min: 0.0,
                max: 1.0,
            },
            unit: "",
            doc: "a gain",
        },
        ParamSpec {
            name: "count",
            kind: ParamKind::Integer {
                default: 3,
                min: 1,
                max: 9,
            },
            unit: "",
            doc: "a count",
        },
        ParamSpec {
            name: "mode",
            kind: ParamKind::Choice {
                default: "a",
                options: &["a", "b"],
            },
            unit: "",
            doc: "a mode",
        },
        ParamSpec {
            name: "on",
            kind: ParamKind::Bool { default: true },
            unit: "",
            doc: "a switch",
        },
    ];

    #[test]
    fn defaults_and_overrides() {
        let p =
            Params::from_assignments(SPECS, ["gain=0.5", "count=4", "mode=b", "on=false"]).unwrap();
        assert_eq!(p.real("gain").unwrap(), 0.5);
        assert_eq!(p.integer("count").unwrap(), 4);
        assert_eq!(p.choice("mode").unwrap(), "b");
        assert!(!p.flag("on").unwrap());
        let d = Params::defaults(SPECS);
        assert_eq!(d.real("gain").unwrap(), 0.02);
    }

    #[test]
    fn refusals_name_the_parameter() {
        let err = |a: &str| Params::from_assignments(SPECS, [a]).unwrap_err();
        assert!(matches!(err("gian=1"), ParamError::Unknown { name, .. } if name == "gian"));
        assert!(matches!(err("gain=2"), ParamError::OutOfRange { name, .. } if name == "gain"));
        assert!(matches!(err("gain=x"), ParamError::Invalid { name, .. } if name == "gain"));
        assert!(matches!(err("count=2.5"), ParamError::Invalid { name, .. } if name == "count"));
        assert!(matches!(err("mode=c"), ParamError::OutOfRange { name, .. } if name == "mode"));
        assert!(matches!(err("gain"), ParamError::Malformed(_)));
        let json = Params::resolve(SPECS, [("gain".to_string(), ParamValue::Bool(true))]);
        assert!(matches!(json, Err(ParamError::Invalid { .. })));
    }

    choice_enum! {
        /// A test mode.
        enum Shade {
            Light = "light",
            Dark = "dark",
        }
    }

    param_table! {
        /// A test table.
        struct TestParams in TEST_PARAMS {
            gain: f64 = real(0.25, 0.0, 1.0, "s", "a gain"),
            count: usize = integer(3, 0, 9, "a count"),
            shade: Shade = choice(Shade::Dark, "a shade"),
            on: bool = flag(true, "a switch"),
        }
    }

    #[test]
    fn a_typed_table_declares_its_specs_and_reads_its_fields() {
        let names: Vec<&str> = TEST_PARAMS.iter().map(|s| s.name).collect();
        assert_eq!(names, ["gain", "count", "shade", "on"]);
        assert_eq!(TEST_PARAMS[0].unit, "s");
        assert_eq!(TEST_PARAMS[2].range_text(), "light | dark");
        assert_eq!(
            TEST_PARAMS[2].default_value(),
            ParamValue::Text("dark".into())
        );

        let typed = TestParams::from_params(&Params::defaults(TEST_PARAMS)).unwrap();
        assert_eq!(
            typed,
            TestParams {
                gain: 0.25,
                count: 3,
                shade: Shade::Dark,
                on: true
            }
        );
        let p = Params::from_assignments(TEST_PARAMS, ["shade=light", "count=7", "on=no"]).unwrap();
        let typed = TestParams::from_params(&p).unwrap();
        assert_eq!(
            (typed.shade, typed.count, typed.on),
            (Shade::Light, 7, false)
        );
        assert_eq!(typed.to_params(), p);
    }

    #[test]
    fn a_choice_word_outside_the_enum_is_an_error_not_a_default() {
        // Values that bypass the table's check (a hand-built set) are still
        // refused by the typed read, naming the parameter.
        let p = Params::from_checked([
            ("gain", ParamValue::Number(0.5)),
            ("count", ParamValue::Number(1.0)),
            ("shade", ParamValue::Text("grey".into())),
            ("on", ParamValue::Bool(true)),
        ]);
        let err = TestParams::from_params(&p).unwrap_err();
        assert!(
            matches!(&err, ParamError::Invalid { name, expected, .. } if name == "shade" && expected == "light | dark"),
            "{err}"
        );
        let negative = Params::from_checked([
            ("gain", ParamValue::Number(0.5)),
            ("count", ParamValue::Number(-1.0)),
            ("shade", ParamValue::Text("dark".into())),
            ("on", ParamValue::Bool(true)),
        ]);
        assert!(TestParams::from_params(&negative).is_err());
    }
}
