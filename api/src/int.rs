//! Lenient integer fields: JSON Schema counts `3.0` as an integer, so the
//! wire types accept integral floats wherever they take an integer (and
//! still refuse `3.5`, negatives and out-of-range values).

use serde::de::{self, Deserializer, Visitor};

struct Integer<const MAX: u64>;

impl<const MAX: u64> Visitor<'_> for Integer<MAX> {
    type Value = u64;

    fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "an integer in 0..={MAX}")
    }

    fn visit_u64<E: de::Error>(self, v: u64) -> Result<u64, E> {
        if v <= MAX {
            Ok(v)
        } else {
            Err(E::invalid_value(de::Unexpected::Unsigned(v), &self))
        }
    }

    fn visit_i64<E: de::Error>(self, v: i64) -> Result<u64, E> {
        u64::try_from(v)
            .map_err(|_| E::invalid_value(de::Unexpected::Signed(v), &self))
            .and_then(|v| self.visit_u64(v))
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> Result<u64, E> {
        if v.fract() == 0.0 && v >= 0.0 && v <= MAX as f64 {
            Ok(v as u64)
        } else {
            Err(E::invalid_value(de::Unexpected::Float(v), &self))
        }
    }
}

/// A `u32`.
pub fn u32<'de, D: Deserializer<'de>>(d: D) -> Result<u32, D::Error> {
    d.deserialize_any(Integer::<{ u32::MAX as u64 }>)
        .map(|v| v as u32)
}

/// An optional `u32`.
pub fn opt_u32<'de, D: Deserializer<'de>>(d: D) -> Result<Option<u32>, D::Error> {
    struct Opt;
    impl<'de> Visitor<'de> for Opt {
        type Value = Option<u32>;
        fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("an integer or null")
        }
        fn visit_none<E: de::Error>(self) -> Result<Self::Value, E> {
            Ok(None)
        }
        fn visit_unit<E: de::Error>(self) -> Result<Self::Value, E> {
            Ok(None)
        }
        fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
            u32(d).map(Some)
        }
    }
    d.deserialize_option(Opt)
}

/// A `u64` no larger than `i64::MAX` (the range of the schema's `int64`).
pub fn u63<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
    d.deserialize_any(Integer::<{ i64::MAX as u64 }>)
}

#[cfg(test)]
mod tests {
    #[derive(Debug, serde::Deserialize)]
    struct T {
        #[serde(deserialize_with = "super::u32")]
        a: u32,
        #[serde(default, deserialize_with = "super::opt_u32")]
        b: Option<u32>,
        #[serde(deserialize_with = "super::u63")]
        c: u64,
    }

    fn parse(s: &str) -> Result<T, serde_json::Error> {
        serde_json::from_str(s)
    }

    #[test]
    fn integral_floats_are_integers_and_others_are_not() {
        let t = parse(r#"{"a": 3.0, "b": 4, "c": 5}"#).unwrap();
        assert_eq!((t.a, t.b, t.c), (3, Some(4), 5));
        assert_eq!(parse(r#"{"a": 3, "b": null, "c": 0}"#).unwrap().b, None);
        assert_eq!(parse(r#"{"a": 3, "c": 0}"#).unwrap().b, None);
        for bad in [
            r#"{"a": 3.5, "c": 0}"#,
            r#"{"a": -1, "c": 0}"#,
            r#"{"a": 4294967296, "c": 0}"#,
            r#"{"a": "3", "c": 0}"#,
            r#"{"a": 1, "c": 9223372036854775808}"#,
        ] {
            assert!(parse(bad).is_err(), "{bad}");
        }
    }
}
