//! Strict JSON for configuration and data files: a duplicate key is an error (serde_json keeps
//! the last one silently), and a struct must be a JSON object (serde_json also fills a struct
//! from an array, by position: `"trijoint": [1, 2]` would silently mean d = 1, α1 = 2°).
//!
//! A document is first read into a [`Value`] by [`Unique`], which refuses duplicate keys; then a
//! type is taken from the value by [`Strict`], a deserializer over a `&Value` that refuses an
//! array where a struct is expected. serde's derived `Deserialize` accepts both shapes and
//! leaves the choice to the format (serde-rs/serde#1587), so the format is where it is made.

use serde::de::value::{MapDeserializer, SeqDeserializer};
use serde::de::{self, Deserializer, IntoDeserializer, MapAccess, SeqAccess, Visitor};
use serde_json::{Map, Number, Value};

/// A JSON value read with every object's keys unique.
pub struct Unique(pub Value);

impl<'de> de::Deserialize<'de> for Unique {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        deserializer.deserialize_any(UniqueVisitor).map(Unique)
    }
}

struct UniqueVisitor;

impl<'de> Visitor<'de> for UniqueVisitor {
    type Value = Value;

    fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("a JSON value")
    }

    fn visit_bool<E>(self, v: bool) -> Result<Value, E> {
        Ok(Value::Bool(v))
    }

    fn visit_i64<E>(self, v: i64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }

    fn visit_u64<E>(self, v: u64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> Result<Value, E> {
        Number::from_f64(v)
            .map(Value::Number)
            .ok_or_else(|| E::custom("a number that is not finite"))
    }

    fn visit_str<E>(self, v: &str) -> Result<Value, E> {
        Ok(Value::String(v.to_owned()))
    }

    fn visit_string<E>(self, v: String) -> Result<Value, E> {
        Ok(Value::String(v))
    }

    fn visit_unit<E>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }

    fn visit_none<E>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }

    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        d.deserialize_any(self)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Value, A::Error> {
        let mut items = Vec::new();
        while let Some(Unique(v)) = seq.next_element()? {
            items.push(v);
        }
        Ok(Value::Array(items))
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Value, A::Error> {
        let mut object = Map::new();
        while let Some(key) = map.next_key::<String>()? {
            if object.contains_key(&key) {
                return Err(de::Error::custom(format!("duplicate key \"{}\"", shorten(&key))));
            }
            let Unique(v) = map.next_value()?;
            object.insert(key, v);
        }
        Ok(Value::Object(object))
    }
}

/// A deserializer over a JSON value that takes a struct from an object only.
#[derive(Clone, Copy)]
pub struct Strict<'a>(pub &'a Value);

type Error = serde_json::Error;

impl<'de> IntoDeserializer<'de, Error> for Strict<'de> {
    type Deserializer = Self;

    fn into_deserializer(self) -> Self {
        self
    }
}

impl<'de> Deserializer<'de> for Strict<'de> {
    type Error = Error;

    fn deserialize_any<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        match self.0 {
            Value::Null => visitor.visit_unit(),
            Value::Bool(b) => visitor.visit_bool(*b),
            Value::Number(n) => match (n.as_u64(), n.as_i64(), n.as_f64()) {
                (Some(u), _, _) => visitor.visit_u64(u),
                (_, Some(i), _) => visitor.visit_i64(i),
                (_, _, Some(f)) => visitor.visit_f64(f),
                _ => Err(de::Error::custom("a number out of range")),
            },
            Value::String(s) => visitor.visit_borrowed_str(s),
            Value::Array(items) => {
                let mut seq = SeqDeserializer::new(items.iter().map(Strict));
                let v = visitor.visit_seq(&mut seq)?;
                seq.end()?;
                Ok(v)
            }
            Value::Object(map) => {
                let mut access = MapDeserializer::new(map.iter().map(|(k, v)| (k.as_str(), Strict(v))));
                let v = visitor.visit_map(&mut access)?;
                access.end()?;
                Ok(v)
            }
        }
    }

    fn deserialize_option<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        match self.0 {
            Value::Null => visitor.visit_none(),
            _ => visitor.visit_some(self),
        }
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        _fields: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Error> {
        match self.0 {
            Value::Object(_) => self.deserialize_any(visitor),
            other => Err(de::Error::invalid_type(unexpected(other), &visitor)),
        }
    }

    fn deserialize_enum<V: Visitor<'de>>(
        self,
        _name: &'static str,
        _variants: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Error> {
        // The files use unit variants only: a string names the variant.
        match self.0 {
            Value::String(s) => visitor.visit_enum(s.as_str().into_deserializer()),
            other => Err(de::Error::invalid_type(unexpected(other), &visitor)),
        }
    }

    fn deserialize_newtype_struct<V: Visitor<'de>>(self, _name: &'static str, visitor: V) -> Result<V::Value, Error> {
        visitor.visit_newtype_struct(self)
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string
        bytes byte_buf unit unit_struct seq tuple tuple_struct map identifier ignored_any
    }
}

/// How a value reads in "invalid type: …" messages.
fn unexpected(v: &Value) -> de::Unexpected<'_> {
    match v {
        Value::Null => de::Unexpected::Unit,
        Value::Bool(b) => de::Unexpected::Bool(*b),
        Value::Number(n) => match (n.as_u64(), n.as_i64(), n.as_f64()) {
            (Some(u), _, _) => de::Unexpected::Unsigned(u),
            (_, Some(i), _) => de::Unexpected::Signed(i),
            (_, _, Some(f)) => de::Unexpected::Float(f),
            _ => de::Unexpected::Other("number"),
        },
        Value::String(s) => de::Unexpected::Str(s),
        Value::Array(_) => de::Unexpected::Seq,
        Value::Object(_) => de::Unexpected::Map,
    }
}

/// Takes a `T` from a value strictly, with the JSON path of the first problem.
pub fn from_value<'a, T: de::Deserialize<'a>>(value: &'a Value) -> Result<T, serde_path_to_error::Error<Error>> {
    serde_path_to_error::deserialize(Strict(value))
}

/// Takes a `T` from the section of a document at JSON path `prefix` (`kinematics`,
/// `task_classes[0].programs[1].params`), strictly; a problem names the full path of the element.
pub fn section<T: de::DeserializeOwned>(value: &Value, prefix: &str) -> Result<T, crate::problem::Problem> {
    from_value(value).map_err(|e| {
        let inner = e.path().to_string();
        let at = if inner == "." { String::new() } else { inner };
        crate::problem::Problem::new(at, e.into_inner().to_string()).under(prefix)
    })
}

/// A text cut to a readable length for a message: a 50 MB string value is not echoed whole.
pub fn shorten(text: &str) -> std::borrow::Cow<'_, str> {
    const MAX: usize = 200;
    match text.char_indices().nth(MAX) {
        None => std::borrow::Cow::Borrowed(text),
        Some((cut, _)) => std::borrow::Cow::Owned(format!("{}… ({} bytes in all)", &text[..cut], text.len())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Geometry {
        d: f64,
        alpha: f64,
        travel: [f64; 2],
        name: Option<String>,
    }

    fn read(text: &str) -> Result<Value, String> {
        let mut de = serde_json::Deserializer::from_str(text);
        serde_path_to_error::deserialize::<_, Unique>(&mut de)
            .map(|u| u.0)
            .map_err(|e| format!("{}: {}", e.path(), e.inner()))
    }

    #[test]
    fn a_struct_from_an_array_is_refused_with_its_path() {
        let v = read(r#"{"g": [1, 2, [0, 250], null]}"#).unwrap();
        #[derive(Debug, Deserialize)]
        #[allow(dead_code)]
        struct Top {
            g: Geometry,
        }
        let e = from_value::<Top>(&v).unwrap_err();
        assert_eq!(e.path().to_string(), "g");
        assert_eq!(
            e.into_inner().to_string(),
            "invalid type: sequence, expected struct Geometry"
        );
        // Arrays still fill arrays, objects structs.
        let v = read(r#"{"d": 600, "alpha": 60.5, "travel": [0, 250], "name": null}"#).unwrap();
        let g: Geometry = from_value(&v).unwrap();
        assert_eq!(g.travel, [0.0, 250.0]);
    }

    #[test]
    fn duplicate_keys_are_refused_with_their_path() {
        assert_eq!(
            read(r#"{"a": {"b": 1, "b": 2}}"#).unwrap_err(),
            "a: duplicate key \"b\" at line 1 column 18"
        );
        assert!(read(r#"[{"b": 1}, {"b": 2}]"#).is_ok());
    }

    #[test]
    fn enums_and_numbers_keep_their_meaning() {
        #[derive(Debug, Deserialize, PartialEq)]
        #[serde(rename_all = "lowercase")]
        enum Reaction {
            Log,
            Error,
        }
        assert_eq!(from_value::<Reaction>(&Value::from("log")).unwrap(), Reaction::Log);
        let e = from_value::<Reaction>(&Value::from(42))
            .unwrap_err()
            .into_inner()
            .to_string();
        assert_eq!(e, "invalid type: integer `42`, expected enum Reaction");
        assert_eq!(
            from_value::<u16>(&Value::from(70000))
                .unwrap_err()
                .into_inner()
                .to_string(),
            "invalid value: integer `70000`, expected u16"
        );
        let _ = Reaction::Error;
    }
}
