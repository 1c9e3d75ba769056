//! Deserialisation helpers for request bodies whose errors keep the exact path of the bad field.
//!
//! `serde_path_to_error` (the API's JSON extractor) tracks the path through every map and
//! sequence serde visits, but two common shapes defeat it:
//! - A fixed-size array (`[f64; 3]`) stops after its `N`th item and leaves the rest to the
//!   JSON reader, which reports "trailing characters" as a syntax error. [`exact`] reads the
//!   whole sequence and says how many items came ("expected 3 items, got 4") at the array.
//! - An internally tagged enum is buffered before its variant is read, so an error inside it
//!   stops at the enum (`$.shape`). [`tagged`] reads the variant from a `serde_json::Value`,
//!   tracks the path inside it, and carries that path in the error's message, where
//!   [`split_inner_path`] finds it again (the extractor appends it to the outer path).

use std::fmt;
use std::marker::PhantomData;

use serde::Deserialize;
use serde::de::{self, DeserializeSeed, Deserializer, IgnoredAny, SeqAccess, Visitor};
use serde_json::Value;

/// Deserialises a fixed-size array, or an `Option` or `Vec` of them, refusing any other item
/// count with "expected N items, got M" at the array's own path. Use with
/// `#[serde(deserialize_with = "crate::wire::exact")]` (plus `default` on an `Option` field).
pub fn exact<'de, D: Deserializer<'de>, A: Exact<'de>>(d: D) -> Result<A, D::Error> {
    A::deserialize_exact(d)
}

/// A value [`exact`] can read.
pub trait Exact<'de>: Sized {
    fn deserialize_exact<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error>;
}

impl<'de, T: Deserialize<'de>, const N: usize> Exact<'de> for [T; N] {
    fn deserialize_exact<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Items<T, const N: usize>(PhantomData<T>);
        impl<'de, T: Deserialize<'de>, const N: usize> Visitor<'de> for Items<T, N> {
            type Value = [T; N];
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                write!(f, "an array of {N} items")
            }
            fn visit_seq<S: SeqAccess<'de>>(self, mut seq: S) -> Result<[T; N], S::Error> {
                let mut items = Vec::with_capacity(N);
                while items.len() < N {
                    match seq.next_element()? {
                        Some(item) => items.push(item),
                        None => break,
                    }
                }
                let mut got = items.len();
                // Count (without keeping) what lies beyond N, so the message says how many.
                while seq.next_element::<IgnoredAny>()?.is_some() {
                    got += 1;
                }
                if got != N {
                    return Err(de::Error::custom(format!("expected {N} items, got {got}")));
                }
                items
                    .try_into()
                    .map_err(|_| de::Error::custom(format!("expected {N} items, got {got}")))
            }
        }
        d.deserialize_seq(Items::<T, N>(PhantomData))
    }
}

impl<'de, A: Exact<'de>> Exact<'de> for Option<A> {
    fn deserialize_exact<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Maybe<A>(PhantomData<A>);
        impl<'de, A: Exact<'de>> Visitor<'de> for Maybe<A> {
            type Value = Option<A>;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an array or null")
            }
            fn visit_none<E: de::Error>(self) -> Result<Option<A>, E> {
                Ok(None)
            }
            fn visit_unit<E: de::Error>(self) -> Result<Option<A>, E> {
                Ok(None)
            }
            fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Option<A>, D::Error> {
                A::deserialize_exact(d).map(Some)
            }
        }
        d.deserialize_option(Maybe::<A>(PhantomData))
    }
}

impl<'de, A: Exact<'de>> Exact<'de> for Vec<A> {
    fn deserialize_exact<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct One<A>(PhantomData<A>);
        impl<'de, A: Exact<'de>> DeserializeSeed<'de> for One<A> {
            type Value = A;
            fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<A, D::Error> {
                A::deserialize_exact(d)
            }
        }
        struct Many<A>(PhantomData<A>);
        impl<'de, A: Exact<'de>> Visitor<'de> for Many<A> {
            type Value = Vec<A>;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a sequence")
            }
            fn visit_seq<S: SeqAccess<'de>>(self, mut seq: S) -> Result<Vec<A>, S::Error> {
                // Each item through the same access, so its index stays on the error path.
                let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(4096));
                while let Some(item) = seq.next_element_seed(One::<A>(PhantomData))? {
                    out.push(item);
                }
                Ok(out)
            }
        }
        d.deserialize_seq(Many::<A>(PhantomData))
    }
}

/// Opens and closes the path inside an error message (a control character that serde's own
/// messages never contain: they quote input with escapes).
const INNER: char = '\u{1f}';

/// `message` of an error found at `suffix` (`.radius`, `.vertices[2]`) below where it is
/// reported.
fn with_inner_path(suffix: &str, message: &str) -> String {
    // An error that already carries a path from a nested tagged enum: join the two.
    match split_inner_path(message) {
        Some((inner, rest)) => format!("{INNER}{suffix}{inner}{INNER}{rest}"),
        None => format!("{INNER}{suffix}{INNER}{message}"),
    }
}

/// The path below the reported one and the plain message, if `message` carries one
/// ([`tagged`]).
pub fn split_inner_path(message: &str) -> Option<(&str, &str)> {
    message.strip_prefix(INNER)?.split_once(INNER)
}

/// A `serde_path_to_error` path as the tail of a JSONPath: `.a.b[2]`, `["odd key"]`.
pub fn path_suffix<'a>(
    segments: impl IntoIterator<Item = &'a serde_path_to_error::Segment>,
) -> String {
    use serde_path_to_error::Segment;
    let mut out = String::new();
    for seg in segments {
        match seg {
            Segment::Seq { index } => out.push_str(&format!("[{index}]")),
            Segment::Map { key } => out.push_str(&key_segment(key)),
            Segment::Enum { variant } => {
                out.push('.');
                out.push_str(variant);
            }
            Segment::Unknown => out.push_str(".?"),
        }
    }
    out
}

/// `.key` for a plain key, `["key"]` otherwise.
pub fn key_segment(key: &str) -> String {
    let simple = !key.is_empty() && key.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    if simple {
        format!(".{key}")
    } else {
        format!("[{key:?}]")
    }
}

/// Reads an internally tagged enum (`{"type": "sphere", "radius": 0.1}`) through `Twin`, an
/// externally tagged copy of it (`{"sphere": {"radius": 0.1}}`), so that a bad field is
/// reported at its own path (`.radius`) rather than at the enum. `what` names the enum in the
/// message for a value that is not an object.
pub fn tagged<'de, D, Twin>(d: D, tag: &'static str, what: &'static str) -> Result<Twin, D::Error>
where
    D: Deserializer<'de>,
    Twin: serde::de::DeserializeOwned,
{
    let mut fields = d.deserialize_map(Fields(what))?;
    let variant = match fields.remove(tag) {
        Some(Value::String(name)) => name,
        Some(other) => {
            let e = <serde_json::Error as de::Error>::invalid_type(unexpected(&other), &"a string");
            return Err(de::Error::custom(with_inner_path(
                &key_segment(tag),
                &e.to_string(),
            )));
        }
        None => return Err(de::Error::missing_field(tag)),
    };
    let external = Value::Object([(variant, Value::Object(fields))].into_iter().collect());
    serde_path_to_error::deserialize(external).map_err(|e| {
        // The twin's variant is the tag, not a field of the request: drop it from the path.
        let path = path_suffix(
            e.path()
                .iter()
                .skip_while(|s| matches!(s, serde_path_to_error::Segment::Enum { .. })),
        );
        let message = e.into_inner().to_string();
        // An unknown variant fails before any variant is entered: it is the tag's fault.
        let path = if path.is_empty() && message.starts_with("unknown variant") {
            key_segment(tag)
        } else {
            path
        };
        de::Error::custom(with_inner_path(&path, &message))
    })
}

/// The fields of a tagged enum's object, refusing a repeated key as a derived struct would (a
/// `Value` would keep the last silently).
struct Fields(&'static str);

impl<'de> Visitor<'de> for Fields {
    type Value = serde_json::Map<String, Value>;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(self.0)
    }
    fn visit_map<A: de::MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
        let mut fields = serde_json::Map::new();
        while let Some(key) = map.next_key::<String>()? {
            if fields.contains_key(&key) {
                let message = format!("duplicate field `{key}`");
                return Err(de::Error::custom(with_inner_path(
                    &key_segment(&key),
                    &message,
                )));
            }
            // Through the same access, so that e.g. a number out of range keeps its path.
            let value = map.next_value::<Value>()?;
            fields.insert(key, value);
        }
        Ok(fields)
    }
}

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

/// A request document read outside HTTP (the CLI's request files), its error in the API's
/// terms: "`$.object.shape.radius`: invalid type ...".
pub fn from_value<T: de::DeserializeOwned>(value: serde_json::Value) -> Result<T, String> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let (path, message) = locate(&e);
        format!("{path}: {message}")
    })
}

/// The JSONPath (`$`, `$.a.b[2]`) and message of a serde error: below a tagged enum (whose
/// message carries the rest of the path, `tagged`), at a missing or unknown field
/// itself rather than its parent object.
pub fn locate(e: &serde_path_to_error::Error<serde_json::Error>) -> (String, String) {
    let mut path = format!("${}", path_suffix(e.path()));
    let inner = e.inner();
    // serde_json appends " at line L column C"; the path says where, so keep just the message.
    let full = inner.to_string();
    let mut message = match full.rfind(" at line ") {
        Some(i) if inner.line() > 0 => full[..i].to_owned(),
        _ => full,
    };
    if let Some((below, rest)) = split_inner_path(&message) {
        path.push_str(below);
        message = rest.to_owned();
    }
    if let Some(rest) = message.strip_prefix("missing field `")
        && let Some(name) = rest.strip_suffix('`')
    {
        path.push_str(&key_segment(name));
    }
    path = with_unknown_field(path, &message);
    (path, message)
}

/// The path of an unknown field, also inside an internally tagged enum: serde buffers such an
/// enum's content and reads the variant from the buffer, so the tracked path stops at the
/// enum (`$.object.shape`) while the message names the field.
fn with_unknown_field(path: String, message: &str) -> String {
    let Some(name) = message
        .strip_prefix("unknown field `")
        .and_then(|rest| rest.split('`').next())
    else {
        return path;
    };
    let segment = key_segment(name);
    if path.ends_with(&segment) {
        path
    } else {
        format!("{path}{segment}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Deserialize)]
    #[allow(dead_code)]
    struct Body {
        #[serde(deserialize_with = "exact")]
        p: [f64; 3],
        #[serde(default, deserialize_with = "exact")]
        q: Option<[f64; 2]>,
        #[serde(default, deserialize_with = "exact")]
        v: Vec<[u32; 2]>,
    }

    fn error(json: &str) -> (String, String) {
        let mut de = serde_json::Deserializer::from_str(json);
        let e = serde_path_to_error::deserialize::<_, Body>(&mut de).unwrap_err();
        let message = e.inner().to_string();
        let message = message.split(" at line ").next().unwrap().to_owned();
        (e.path().to_string(), message)
    }

    #[test]
    fn exact_arrays_say_how_many_items_came_at_the_array() {
        assert_eq!(
            error(r#"{"p": [1, 2, 3, 4]}"#),
            ("p".into(), "expected 3 items, got 4".into())
        );
        assert_eq!(
            error(r#"{"p": [1, 2]}"#),
            ("p".into(), "expected 3 items, got 2".into())
        );
        assert_eq!(
            error(r#"{"p": [1, 2, 3], "q": [1, 2, 3]}"#),
            ("q".into(), "expected 2 items, got 3".into())
        );
        assert_eq!(
            error(r#"{"p": [1, 2, 3], "v": [[1, 2], [1, 2, 3]]}"#),
            ("v[1]".into(), "expected 2 items, got 3".into())
        );
        assert_eq!(
            error(r#"{"p": [1, "x", 3]}"#).0,
            "p[1]",
            "a bad item keeps its index"
        );
        let ok: Body = serde_json::from_str(r#"{"p": [1, 2, 3], "q": null}"#).unwrap();
        assert!(ok.q.is_none() && ok.v.is_empty());
    }

    #[test]
    fn inner_paths_round_trip_through_a_message() {
        let m = with_inner_path(".shape", &with_inner_path(".radius", "bad"));
        assert_eq!(split_inner_path(&m), Some((".shape.radius", "bad")));
        assert_eq!(split_inner_path("bad"), None);
    }
}
