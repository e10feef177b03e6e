//! The first path of [`super::parse_reading`]: a strict scanner for the
//! flat object a reading is, which fills [`RawReading`] without serde's
//! per-token machinery. It knows only what a reading holds (the known
//! keys, each once; numbers, the sensor's name, arrays of numbers;
//! whitespace between tokens) and gives up on anything else (an escape,
//! `null`, an unknown key, a number out of range or longer than
//! [`MAX_NUMBER_BYTES`], a syntax error), which serde then parses or
//! explains. Numbers are read by the standard library's correctly rounded
//! parser, as serde_json's `float_roundtrip` reads them, so both paths
//! give the same bits; serde_json's long-number path (hundreds of digits)
//! can round a halfway case the other way, so long numbers are serde's.

use super::{RawReading, SensorKind, SensorTag};

/// Longest number text the scanner reads: a shortest-round-trip f64 takes
/// at most 24 bytes, so a gateway's numbers fit with room to spare.
const MAX_NUMBER_BYTES: usize = 40;

/// The reading in `bytes`, or `None` to leave it to serde.
pub(super) fn scan(bytes: &[u8]) -> Option<RawReading> {
    // Checked once, so that any slice between ASCII tokens is text.
    let text = std::str::from_utf8(bytes).ok()?;
    let mut scanner = Scanner { text, at: 0 };
    let mut raw = RawReading::default();
    scanner.expect(b'{')?;
    if scanner.peek()? == b'}' {
        scanner.at += 1;
        return scanner.finished().then_some(raw);
    }
    let mut seen = 0u32;
    loop {
        let key = scanner.string()?;
        scanner.expect(b':')?;
        let (bit, field) = field(key)?;
        if seen & bit != 0 {
            return None; // a duplicate: serde names it
        }
        seen |= bit;
        match field {
            Key::T => raw.t = Some(scanner.number()?),
            Key::Sensor => {
                let name = scanner.string()?;
                raw.sensor = Some(match SensorKind::from_name(name) {
                    Some(kind) => SensorTag::Known(kind),
                    None => SensorTag::Unknown(name.to_string()),
                });
            }
            Key::PitchDeg => raw.pitch_deg = Some(scanner.number()?),
            Key::RollDeg => raw.roll_deg = Some(scanner.number()?),
            Key::YawDeg => raw.yaw_deg = Some(scanner.number()?),
            Key::TempC => raw.temp_c = Some(scanner.number()?),
            Key::AccelMps2 => raw.accel_mps2 = Some(scanner.triple()?),
            Key::GyroDps => raw.gyro_dps = Some(scanner.triple()?),
            Key::FieldUt => raw.field_ut = Some(scanner.triple()?),
            Key::HeightM => raw.height_m = Some(scanner.number()?),
            Key::DistanceM => raw.distance_m = Some(scanner.number()?),
            Key::EastingM => raw.easting_m = Some(scanner.number()?),
            Key::NorthingM => raw.northing_m = Some(scanner.number()?),
            Key::Ring => raw.ring = Some(scanner.number()?),
            Key::StrokesMm => raw.strokes_mm = Some(scanner.numbers()?),
            Key::Position => raw.key = Some(scanner.number()?),
            Key::ClearanceMm => raw.clearance_mm = Some(scanner.numbers()?),
        }
        match scanner.next()? {
            b',' => continue,
            b'}' => break,
            _ => return None,
        }
    }
    scanner.finished().then_some(raw)
}

#[derive(Clone, Copy)]
enum Key {
    T,
    Sensor,
    PitchDeg,
    RollDeg,
    YawDeg,
    TempC,
    AccelMps2,
    GyroDps,
    FieldUt,
    HeightM,
    DistanceM,
    EastingM,
    NorthingM,
    Ring,
    StrokesMm,
    /// `key`: an advance's key position.
    Position,
    ClearanceMm,
}

/// A known key's bit (for duplicates) and field.
fn field(key: &str) -> Option<(u32, Key)> {
    let field = match key {
        "t" => Key::T,
        "sensor" => Key::Sensor,
        "pitch_deg" => Key::PitchDeg,
        "roll_deg" => Key::RollDeg,
        "yaw_deg" => Key::YawDeg,
        "temp_c" => Key::TempC,
        "accel_mps2" => Key::AccelMps2,
        "gyro_dps" => Key::GyroDps,
        "field_ut" => Key::FieldUt,
        "height_m" => Key::HeightM,
        "distance_m" => Key::DistanceM,
        "easting_m" => Key::EastingM,
        "northing_m" => Key::NorthingM,
        "ring" => Key::Ring,
        "strokes_mm" => Key::StrokesMm,
        "key" => Key::Position,
        "clearance_mm" => Key::ClearanceMm,
        _ => return None,
    };
    Some((1 << field as u32, field))
}

struct Scanner<'a> {
    text: &'a str,
    at: usize,
}

impl<'a> Scanner<'a> {
    /// The text's bytes.
    fn bytes(&self) -> &'a [u8] {
        self.text.as_bytes()
    }

    /// The next byte after whitespace, not consumed.
    fn peek(&mut self) -> Option<u8> {
        while let Some(&b) = self.bytes().get(self.at) {
            if !matches!(b, b' ' | b'\t' | b'\n' | b'\r') {
                return Some(b);
            }
            self.at += 1;
        }
        None
    }

    /// The next byte after whitespace, consumed.
    fn next(&mut self) -> Option<u8> {
        let b = self.peek()?;
        self.at += 1;
        Some(b)
    }

    fn expect(&mut self, byte: u8) -> Option<()> {
        (self.next()? == byte).then_some(())
    }

    /// Only whitespace is left.
    fn finished(&mut self) -> bool {
        self.peek().is_none()
    }

    /// A string without escapes or control characters.
    fn string(&mut self) -> Option<&'a str> {
        self.expect(b'"')?;
        let start = self.at;
        loop {
            match *self.bytes().get(self.at)? {
                b'"' => break,
                b'\\' | 0..0x20 => return None,
                _ => self.at += 1,
            }
        }
        self.at += 1;
        // Both ends are at a quote: ASCII, so on character boundaries.
        self.text.get(start..self.at - 1)
    }

    /// A finite number in JSON's grammar: -?(0|[1-9][0-9]*)(.[0-9]+)?([eE][+-]?[0-9]+)?
    fn number(&mut self) -> Option<f64> {
        self.peek()?;
        let start = self.at;
        let digits = |s: &mut Self| {
            let from = s.at;
            while s.bytes().get(s.at).is_some_and(u8::is_ascii_digit) {
                s.at += 1;
            }
            s.at > from
        };
        if self.bytes().get(self.at) == Some(&b'-') {
            self.at += 1;
        }
        match self.bytes().get(self.at)? {
            b'0' => self.at += 1,
            b'1'..=b'9' => {
                digits(self);
            }
            _ => return None,
        }
        if self.bytes().get(self.at) == Some(&b'.') {
            self.at += 1;
            if !digits(self) {
                return None;
            }
        }
        if matches!(self.bytes().get(self.at), Some(b'e' | b'E')) {
            self.at += 1;
            if matches!(self.bytes().get(self.at), Some(b'+' | b'-')) {
                self.at += 1;
            }
            if !digits(self) {
                return None;
            }
        }
        // A digit right after the number (`01`) is not JSON.
        if self.bytes().get(self.at).is_some_and(u8::is_ascii_digit) {
            return None;
        }
        if self.at - start > MAX_NUMBER_BYTES {
            return None;
        }
        // ASCII from `start` to here: character boundaries.
        let number = self.text.get(start..self.at)?;
        number.parse::<f64>().ok().filter(|v| v.is_finite())
    }

    /// `[x,y,z]`
    fn triple(&mut self) -> Option<[f64; 3]> {
        self.expect(b'[')?;
        let x = self.number()?;
        self.expect(b',')?;
        let y = self.number()?;
        self.expect(b',')?;
        let z = self.number()?;
        self.expect(b']')?;
        Some([x, y, z])
    }

    /// `[x,…]`, empty too.
    fn numbers(&mut self) -> Option<Vec<f64>> {
        self.expect(b'[')?;
        let mut values = Vec::new();
        if self.peek()? == b']' {
            self.at += 1;
            return Some(values);
        }
        loop {
            values.push(self.number()?);
            match self.next()? {
                b',' => continue,
                b']' => return Some(values),
                _ => return None,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::parse_with_serde;
    use super::*;
    use proptest::prelude::*;

    /// What the scanner makes of `text`, or `None` where it leaves it to
    /// serde; and what serde makes of it. Debug output tells -0.0 from 0.0.
    fn both(text: &str) -> (Option<String>, String) {
        let scanned = scan(text.as_bytes()).map(|raw| format!("{:?}", raw.validate()));
        (scanned, format!("{:?}", parse_with_serde(text.as_bytes())))
    }

    #[test]
    fn what_the_scanner_reads_serde_reads_alike() {
        for text in [
            r#"{"t":1772431200.0,"sensor":"imu","accel_mps2":[0.04477387262349498,-0.011569570098347646,-9.774148780791494],"gyro_dps":[0.0035793818422311784,0.3507956778370676,-0.400935021273188]}"#,
            r#"{"t":1772431200,"sensor":"inclinometer","pitch_deg":-0,"roll_deg":-0.0,"temp_c":2E1}"#,
            r#" { "sensor" : "laser" , "t" : 1.7724312e9 , "pitch_deg":1e-400,"roll_deg":0.5,"easting_m":1,"northing_m":2,"height_m":3 } "#,
            r#"{"t":1772431200,"sensor":"advance","ring":12,"strokes_mm":[]}"#,
            r#"{"t":1772431200,"sensor":"advance","ring":12.5}"#,
            r#"{"t":1772431200,"sensor":"advance","ring":3,"strokes_mm":[1500,1502.5]}"#,
            r#"{"t":1772431200,"sensor":"sonar"}"#,
            r#"{"t":1772431200,"sensor":"sonär"}"#,
            r#"{"t":1772431200,"sensor":"level","height_m":95}"#,
            r#"{"t":1772431200,"sensor":"odometer"}"#,
            r#"{}"#,
        ] {
            let (scanned, serde) = both(text);
            let scanned = scanned.unwrap_or_else(|| panic!("not scanned: {text}"));
            assert_eq!(scanned, serde, "{text}");
        }
    }

    #[test]
    fn what_is_not_plainly_a_reading_is_left_to_serde() {
        for text in [
            r#"{"t":1772431200,"t":1772431201,"sensor":"odometer","distance_m":1}"#,
            r#"{"t":01,"sensor":"odometer","distance_m":1}"#,
            r#"{"t":1.,"sensor":"odometer","distance_m":1}"#,
            r#"{"t":.5,"sensor":"odometer","distance_m":1}"#,
            r#"{"t":1e999,"sensor":"odometer","distance_m":1}"#,
            r#"{"t":+1,"sensor":"odometer","distance_m":1}"#,
            r#"{"t":1772431200.00000000000000000000000000000000000000001,"sensor":"odometer","distance_m":1}"#,
            r#"{"t":1772431200,"sensor":"odo\u006deter","distance_m":1}"#,
            r#"{"t":1772431200,"sensor":"odometer","distance_m":null}"#,
            r#"{"t":1772431200,"sensor":"imu","accel_mps2":[1,2],"gyro_dps":[1,2,3]}"#,
            r#"{"t":1772431200,"sensor":"imu","accel_mps2":[1,2,3,4],"gyro_dps":[1,2,3]}"#,
            r#"{"t":1772431200,"sensor":"odometer","distance_m":1,}"#,
            r#"{"t":1772431200,"sensor":"odometer","distance_m":1}x"#,
            r#"{"t":1772431200,"sensor":"odometer","distance_m":1"#,
            r#"{"t":1772431200,"sensor":"odometer","note":"x","distance_m":1}"#,
            r#"{"t":1772431200,"sensor":"sonar","range_m":1}"#,
            r#"[{"t":1772431200}]"#,
            "",
        ] {
            assert_eq!(both(text).0, None, "{text}");
        }
    }

    /// A number as a gateway might write it: every JSON form of its value.
    fn written(value: f64, style: u8) -> String {
        match style % 5 {
            0 => format!("{value}"),
            1 => format!("{value:e}"),
            2 => format!("{value:E}").replace("E", "E+").replace("E+-", "E-"),
            3 => format!("{value:.3}"),
            _ => format!("{}", value.trunc()),
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        /// Readings with any values, key order and spacing, and with a byte
        /// changed: wherever the scanner answers, serde answers the same.
        #[test]
        fn the_scanner_agrees_with_serde(
            values in proptest::collection::vec(
                prop_oneof![
                    any::<f64>().prop_filter("finite", |v| v.is_finite()),
                    -400.0..400.0f64,
                    Just(-0.0f64),
                    Just(1_772_431_200.5f64),
                ],
                7,
            ),
            styles in proptest::collection::vec(any::<u8>(), 7),
            kind in 0usize..4,
            reverse in any::<bool>(),
            space in prop_oneof![Just(""), Just(" "), Just("\n\t ")],
            damage in proptest::option::of((any::<prop::sample::Index>(), any::<u8>())),
        ) {
            let n = |i: usize| written(values[i], styles[i]);
            let mut fields = vec![format!("\"t\":{}", n(0))];
            match kind {
                0 => {
                    fields.push("\"sensor\":\"imu\"".into());
                    fields.push(format!("\"accel_mps2\":[{},{},{}]", n(1), n(2), n(3)));
                    fields.push(format!("\"gyro_dps\":[{},{},{}]", n(4), n(5), n(6)));
                }
                1 => {
                    fields.push("\"sensor\":\"inclinometer\"".into());
                    fields.push(format!("\"pitch_deg\":{}", n(1)));
                    fields.push(format!("\"roll_deg\":{}", n(2)));
                    fields.push(format!("\"temp_c\":{}", n(3)));
                }
                2 => {
                    fields.push("\"sensor\":\"laser\"".into());
                    fields.push(format!("\"pitch_deg\":{}", n(1)));
                    fields.push(format!("\"roll_deg\":{}", n(2)));
                    fields.push(format!("\"easting_m\":{}", n(3)));
                    fields.push(format!("\"northing_m\":{}", n(4)));
                    fields.push(format!("\"height_m\":{}", n(5)));
                }
                _ => {
                    fields.push("\"sensor\":\"advance\"".into());
                    fields.push(format!("\"ring\":{}", n(1)));
                    fields.push(format!("\"strokes_mm\":[{},{}]", n(2), n(3)));
                }
            }
            if reverse {
                fields.reverse();
            }
            let mut text = format!("{{{space}{}{space}}}", fields.join(&format!("{space},{space}")))
                .into_bytes();
            if let Some((at, byte)) = damage {
                let i = at.index(text.len());
                text[i] = byte;
            }
            let text = String::from_utf8_lossy(&text).into_owned();
            let (scanned, serde) = both(&text);
            if let Some(scanned) = scanned {
                prop_assert_eq!(scanned, serde, "{}", text);
            }
        }
    }
}
