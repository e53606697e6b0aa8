//! Typed replies as JSON by their D-Bus keys: a reply is encoded as the
//! `a{sv}` dictionary it is on the wire and that dictionary converted, so no
//! second list of each reply's fields lives anywhere (`sdictl --json`, the
//! Python module's dictionaries).

use std::collections::HashMap;

use serde_json::{json, Map, Value as Json};
use zbus::zvariant::{self, OwnedValue, Value};

/// `reply` (an `a{sv}` type) as a JSON object keyed as on the wire.
pub fn object<T: serde::Serialize + zvariant::Type>(
    reply: &T,
) -> Result<Map<String, Json>, zvariant::Error> {
    let ctxt = zvariant::serialized::Context::new_dbus(zvariant::LE, 0);
    let bytes = zvariant::to_bytes(ctxt, reply)?;
    let (dict, _) = bytes.deserialize::<HashMap<String, OwnedValue>>()?;
    Ok(dict.iter().map(|(k, v)| (k.clone(), value(v))).collect())
}

/// One D-Bus value as JSON: numbers, strings, lists and dictionaries as
/// themselves, a variant as what it holds.
pub fn value(v: &Value<'_>) -> Json {
    match v {
        Value::U8(x) => json!(x),
        Value::Bool(x) => json!(x),
        Value::I16(x) => json!(x),
        Value::U16(x) => json!(x),
        Value::I32(x) => json!(x),
        Value::U32(x) => json!(x),
        Value::I64(x) => json!(x),
        Value::U64(x) => json!(x),
        Value::F64(x) => json!(x),
        Value::Str(s) => json!(s.as_str()),
        Value::ObjectPath(p) => json!(p.as_str()),
        Value::Value(inner) => value(inner),
        Value::Array(a) => Json::Array(a.iter().map(value).collect()),
        Value::Dict(d) => Json::Object(d.iter().map(|(k, v)| (key(k), value(v))).collect()),
        Value::Structure(s) => Json::Array(s.fields().iter().map(value).collect()),
        other => json!(other.to_string()),
    }
}

/// A dictionary key as JSON object keys must be: text.
fn key(k: &Value<'_>) -> String {
    match value(k) {
        Json::String(s) => s,
        other => other.to_string(),
    }
}
