//! The NDJSON field writer every estimate's `write_fields` uses.

/// Writes the fields of one JSON object as serde_json does, commas
/// between them (an estimate's first fields are `t`, `machine`, `engine`);
/// floats and integers with serde_json's own formatters.
pub struct JsonFields<'a> {
    out: &'a mut Vec<u8>,
    floats: &'a mut zmij::Buffer,
    integers: &'a mut itoa::Buffer,
    /// No field written yet in the current object.
    first: bool,
}

impl<'a> JsonFields<'a> {
    /// Fields appended to `out`, with these formatters.
    pub(super) fn new(
        out: &'a mut Vec<u8>,
        floats: &'a mut zmij::Buffer,
        integers: &'a mut itoa::Buffer,
    ) -> JsonFields<'a> {
        JsonFields {
            out,
            floats,
            integers,
            first: true,
        }
    }

    /// A field formatted beforehand (`"key":value`), after a comma unless
    /// it is the first.
    pub(super) fn raw(&mut self, field: &[u8]) {
        if !std::mem::take(&mut self.first) {
            self.out.push(b',');
        }
        self.out.extend_from_slice(field);
    }

    /// `,"key":number` (`null` when not finite, as serde_json writes it).
    pub fn number(&mut self, key: &str, value: f64) {
        self.key(key);
        self.float(value);
    }

    /// `,"key":integer`
    pub fn integer(&mut self, key: &str, value: u64) {
        self.key(key);
        self.out
            .extend_from_slice(self.integers.format(value).as_bytes());
    }

    /// `,"key":true|false`
    pub fn flag(&mut self, key: &str, value: bool) {
        self.key(key);
        self.out
            .extend_from_slice(if value { b"true" } else { b"false" });
    }

    /// `,"key":"word"` for a word that needs no escaping (an enum's name).
    pub fn word(&mut self, key: &str, word: &'static str) {
        debug_assert!(!word.contains(['"', '\\']) && !word.contains(char::is_control));
        self.key(key);
        self.out.push(b'"');
        self.out.extend_from_slice(word.as_bytes());
        self.out.push(b'"');
    }

    /// `,"key":"text"` for any text, escaped as serde_json escapes it.
    pub fn text(&mut self, key: &str, value: &str) {
        self.key(key);
        // Writing into a Vec cannot fail; a failure would leave the
        // field empty, never a panic.
        let _ = serde_json::to_writer(&mut *self.out, value);
    }

    /// `,"key":null`
    pub fn null(&mut self, key: &str) {
        self.key(key);
        self.out.extend_from_slice(b"null");
    }

    /// `,"key":[x,y,z]`
    pub fn triple(&mut self, key: &str, values: &[f64; 3]) {
        self.numbers(key, values);
    }

    /// `,"key":[x,…]`
    pub fn numbers(&mut self, key: &str, values: &[f64]) {
        self.key(key);
        self.out.push(b'[');
        for (i, value) in values.iter().enumerate() {
            if i > 0 {
                self.out.push(b',');
            }
            self.float(*value);
        }
        self.out.push(b']');
    }

    /// `,"key":number|null`
    pub fn optional(&mut self, key: &str, value: Option<f64>) {
        match value {
            Some(value) => self.number(key, value),
            None => self.null(key),
        }
    }

    /// `,"key":{…}`, its fields written by `fields`.
    pub fn object(&mut self, key: &str, fields: impl FnOnce(&mut Self)) {
        self.key(key);
        self.out.push(b'{');
        self.first = true;
        fields(self);
        self.first = false;
        self.out.push(b'}');
    }

    /// `,"key":[{…},{…}]`, each object's fields written by `fields`.
    pub fn objects<T>(&mut self, key: &str, items: &[T], mut fields: impl FnMut(&T, &mut Self)) {
        self.key(key);
        self.out.push(b'[');
        for (i, item) in items.iter().enumerate() {
            if i > 0 {
                self.out.push(b',');
            }
            self.out.push(b'{');
            self.first = true;
            fields(item, self);
            self.first = false;
            self.out.push(b'}');
        }
        self.out.push(b']');
    }

    /// `,"key":`, without the comma before an object's first field.
    fn key(&mut self, key: &str) {
        if !std::mem::take(&mut self.first) {
            self.out.push(b',');
        }
        self.out.push(b'"');
        self.out.extend_from_slice(key.as_bytes());
        self.out.extend_from_slice(b"\":");
    }

    fn float(&mut self, value: f64) {
        if value.is_finite() {
            self.out
                .extend_from_slice(self.floats.format_finite(value).as_bytes());
        } else {
            self.out.extend_from_slice(b"null"); // as serde_json writes non-finite floats
        }
    }
}
