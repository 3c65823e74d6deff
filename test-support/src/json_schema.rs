//! A small structural check of a JSON value against a channel's JSON schema, for the tests
//! that prove a recording's data and schemas agree (a full validator crate would build URL
//! and Unicode tables for this one use).
//!
//! It knows the keywords the derived schemas use: `type` (one or several), `format` of the
//! integer and float types (`uint32` must fit in 32 bits, `float` in an `f32`), `minimum` /
//! `maximum`, `properties` / `required` / `additionalProperties`, `items` / `minItems` /
//! `maxItems`, `enum`, `const`, `anyOf` / `oneOf`, and `$ref` into `$defs`. It is stricter than
//! JSON Schema in one way: a property of the data that the schema does not list is an error
//! even without `additionalProperties: false`, so the data carries nothing the schema does not
//! describe. A keyword it does not know that could constrain the data is an error too, so a
//! schema it cannot fully check never passes.

use serde_json::Value;

/// Keywords that only annotate (no constraint on the data).
const ANNOTATIONS: [&str; 7] = [
    "$schema",
    "$defs",
    "title",
    "description",
    "default",
    "examples",
    "deprecated",
];

/// Keywords [`validate`] checks.
const CHECKED: [&str; 14] = [
    "type",
    "format",
    "minimum",
    "maximum",
    "properties",
    "required",
    "additionalProperties",
    "items",
    "minItems",
    "maxItems",
    "enum",
    "const",
    "anyOf",
    "oneOf",
];

/// What is wrong with `value` against `schema` (empty: it agrees), each item naming where.
pub fn validate(value: &Value, schema: &Value) -> Vec<String> {
    let mut errs = Vec::new();
    check(value, schema, schema, "$", &mut errs);
    errs
}

fn resolve<'a>(root: &'a Value, s: &'a Value, at: &str, errs: &mut Vec<String>) -> &'a Value {
    match s.get("$ref").and_then(Value::as_str) {
        Some(r) => match r.strip_prefix('#').map(|p| root.pointer(p)) {
            Some(Some(t)) => t,
            _ => {
                errs.push(format!("{at}: cannot resolve $ref `{r}`"));
                &Value::Null
            }
        },
        None => s,
    }
}

fn is_type(v: &Value, t: &str) -> bool {
    match t {
        "object" => v.is_object(),
        "array" => v.is_array(),
        "string" => v.is_string(),
        "boolean" => v.is_boolean(),
        "null" => v.is_null(),
        "integer" => v.is_u64() || v.is_i64(),
        "number" => v.is_number(),
        _ => false,
    }
}

fn fits_format(v: &Value, f: &str) -> Option<bool> {
    let unsigned = |max: u64| v.as_u64().is_some_and(|x| x <= max);
    let signed = |lo: i64, hi: i64| v.as_i64().is_some_and(|x| (lo..=hi).contains(&x));
    Some(match f {
        "uint8" => unsigned(u8::MAX.into()),
        "uint16" => unsigned(u16::MAX.into()),
        "uint32" => unsigned(u32::MAX.into()),
        "uint64" | "uint" => v.is_u64(),
        "int8" => signed(i8::MIN.into(), i8::MAX.into()),
        "int16" => signed(i16::MIN.into(), i16::MAX.into()),
        "int32" => signed(i32::MIN.into(), i32::MAX.into()),
        "int64" | "int" => v.as_i64().is_some(),
        "float" => v.as_f64().is_some_and(|x| x.abs() <= f32::MAX as f64),
        "double" => v.is_number(),
        _ => return None,
    })
}

fn check(v: &Value, s: &Value, root: &Value, at: &str, errs: &mut Vec<String>) {
    let s = resolve(root, s, at, errs);
    let Some(obj) = s.as_object() else {
        if s == &Value::Bool(false) {
            errs.push(format!("{at}: the schema allows nothing here"));
        }
        return;
    };
    for k in obj.keys() {
        let known = k == "$ref"
            || k.starts_with("x-")
            || ANNOTATIONS.contains(&k.as_str())
            || CHECKED.contains(&k.as_str());
        if !known {
            errs.push(format!(
                "{at}: the check does not know schema keyword `{k}`"
            ));
        }
    }
    let types: Vec<&str> = match &s["type"] {
        Value::String(t) => vec![t.as_str()],
        Value::Array(ts) => ts.iter().filter_map(Value::as_str).collect(),
        _ => vec![],
    };
    if !types.is_empty() && !types.iter().any(|t| is_type(v, t)) {
        errs.push(format!("{at}: {v} is not {}", types.join(" or ")));
        return;
    }
    if let Some(f) = s["format"].as_str()
        && v.is_number()
    {
        match fits_format(v, f) {
            Some(true) => {}
            Some(false) => errs.push(format!("{at}: {v} is not a {f}")),
            None => errs.push(format!("{at}: the check does not know format `{f}`")),
        }
    }
    if let (Some(min), Some(x)) = (s["minimum"].as_f64(), v.as_f64())
        && x < min
    {
        errs.push(format!("{at}: {v} < {min}"));
    }
    if let (Some(max), Some(x)) = (s["maximum"].as_f64(), v.as_f64())
        && x > max
    {
        errs.push(format!("{at}: {v} > {max}"));
    }
    if let Some(options) = s["enum"].as_array()
        && !options.contains(v)
    {
        errs.push(format!("{at}: {v} is none of {}", s["enum"]));
    }
    if let Some(c) = s.get("const")
        && c != v
    {
        errs.push(format!("{at}: {v} is not {c}"));
    }
    for (key, exactly_one) in [("anyOf", false), ("oneOf", true)] {
        if let Some(options) = s[key].as_array() {
            let ok = options
                .iter()
                .filter(|o| {
                    let mut e = Vec::new();
                    check(v, o, root, at, &mut e);
                    e.is_empty()
                })
                .count();
            if ok == 0 || exactly_one && ok > 1 {
                errs.push(format!("{at}: {v} matches {ok} of the {key} schemas"));
            }
        }
    }
    if let Some(data) = v.as_object() {
        check_fields(data, s, root, at, errs);
    }
    if let Some(items) = v.as_array() {
        check_items(items, s, root, at, errs);
    }
}

/// An object's fields against schema `s`: each by its property's schema (or
/// `additionalProperties`), none unknown, every required one present.
fn check_fields(
    data: &serde_json::Map<String, Value>,
    s: &Value,
    root: &Value,
    at: &str,
    errs: &mut Vec<String>,
) {
    let props = s["properties"].as_object();
    let extra = s.get("additionalProperties");
    for (k, x) in data {
        let here = format!("{at}.{k}");
        match (props.and_then(|p| p.get(k)), extra) {
            (Some(ps), _) => check(x, ps, root, &here, errs),
            (None, Some(ap)) if ap.is_object() => check(x, ap, root, &here, errs),
            (None, _) => errs.push(format!("{at}: field `{k}` is not in the schema")),
        }
    }
    for r in s["required"].as_array().into_iter().flatten() {
        if let Some(r) = r.as_str()
            && !data.contains_key(r)
        {
            errs.push(format!("{at}: required field `{r}` is missing"));
        }
    }
}

/// An array's items against schema `s`: each by `items`, their count within
/// `minItems` / `maxItems`.
fn check_items(items: &[Value], s: &Value, root: &Value, at: &str, errs: &mut Vec<String>) {
    if let Some(is) = s.get("items") {
        for (i, x) in items.iter().enumerate() {
            check(x, is, root, &format!("{at}[{i}]"), errs);
        }
    }
    let n = items.len() as u64;
    if let Some(min) = s["minItems"].as_u64()
        && n < min
    {
        errs.push(format!("{at}: {n} items, fewer than {min}"));
    }
    if let Some(max) = s["maxItems"].as_u64()
        && n > max
    {
        errs.push(format!("{at}: {n} items, more than {max}"));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn schema() -> Value {
        json!({
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "type": "object",
            "properties": {
                "tick": {"type": ["integer", "null"], "format": "uint64", "minimum": 0},
                "n": {"type": "integer", "format": "uint32", "minimum": 0, "x-bit-names": {}},
                "q": {"type": "array", "items": {"type": "number", "format": "float"},
                      "minItems": 2, "maxItems": 2},
                "inner": {"$ref": "#/$defs/Inner"},
            },
            "required": ["tick", "n", "q"],
            "$defs": {"Inner": {"type": "object", "properties": {"b": {"type": "boolean"}}}},
        })
    }

    #[test]
    fn it_accepts_what_agrees_and_names_what_does_not() {
        let s = schema();
        let ok = json!({"tick": null, "n": 3, "q": [0.5, -1.0], "inner": {"b": true}});
        assert_eq!(validate(&ok, &s), Vec::<String>::new());
        let cases = [
            (json!({"tick": -1, "n": 3, "q": [0.5, 1.0]}), "$.tick"),
            (
                json!({"tick": 1, "n": 4294967296u64, "q": [0.5, 1.0]}),
                "uint32",
            ),
            (json!({"tick": 1, "n": 3, "q": [0.5]}), "fewer than 2"),
            (json!({"tick": 1, "n": 3, "q": [0.5, 1, 2]}), "more than 2"),
            (json!({"tick": 1, "n": 3, "q": [0.5, "x"]}), "$.q[1]"),
            (json!({"tick": 1, "n": 3, "q": [0.5, 1e300]}), "float"),
            (json!({"tick": 1, "q": [0.5, 1.0]}), "`n` is missing"),
            (
                json!({"tick": 1, "n": 3, "q": [0.5, 1.0], "z": 0}),
                "`z` is not in",
            ),
            (
                json!({"tick": 1, "n": 3, "q": [0.5, 1.0], "inner": {"b": 1}}),
                "$.inner.b",
            ),
        ];
        for (v, what) in cases {
            let e = validate(&v, &s);
            assert!(e.iter().any(|e| e.contains(what)), "{v}: {e:?}");
        }
        // A keyword it cannot check fails the check rather than passing unchecked.
        let mut s = schema();
        s["properties"]["q"]["uniqueItems"] = json!(true);
        let e = validate(&ok, &s);
        assert!(e.iter().any(|e| e.contains("uniqueItems")), "{e:?}");
    }
}
