//! The result tables the tools write (`scl train`'s loss log, `scl eval`'s CSV files): each a
//! `#[derive(Serialize)]` row struct whose field names are the header, written by `csv`. The
//! number formats are the files' own, kept through these `serialize_with` helpers.

use std::fmt::Display;

use serde::{Serialize, Serializer};

/// `{:.9e}` (ten significant digits), empty when not finite: `#[serde(serialize_with = "sci")]`.
pub fn sci<S: Serializer>(value: &f64, s: S) -> Result<S::Ok, S::Error> {
    if value.is_finite() {
        s.collect_str(&format_args!("{value:.9e}"))
    } else {
        s.serialize_str("")
    }
}

/// [`sci`], empty when `None`.
pub fn sci_opt<S: Serializer>(value: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
    sci(&value.unwrap_or(f64::NAN), s)
}

/// `D` decimals: `#[serde(serialize_with = "fixed::<9, _>")]`.
pub fn fixed<const D: usize, S: Serializer>(value: &f64, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(&format_args!("{value:.D$}"))
}

/// The value's `Display` (`1` rather than serde's `1.0` for a float; a model kind's name).
pub fn display<T: Display, S: Serializer>(value: &T, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(value)
}

/// [`display`], empty when `None`.
pub fn display_opt<T: Display, S: Serializer>(value: &Option<T>, s: S) -> Result<S::Ok, S::Error> {
    match value {
        Some(v) => s.collect_str(v),
        None => s.serialize_str(""),
    }
}

/// CSV text of `rows`, the header from the row type's field names (fields are quoted when
/// they hold a comma or a quote).
pub fn to_csv<R: Serialize>(rows: impl IntoIterator<Item = R>) -> Result<String, csv::Error> {
    let mut w = csv::Writer::from_writer(Vec::new());
    for row in rows {
        w.serialize(row)?;
    }
    let bytes = w
        .into_inner()
        .map_err(|e| csv::Error::from(e.into_error()))?;
    Ok(String::from_utf8_lossy(&bytes).into_owned())
}

/// [`to_csv`] when there may be no rows: then only `header` (which must be the row type's
/// field names; debug builds check it whenever there are rows).
pub fn to_csv_or_header<R: Serialize>(
    header: &str,
    rows: impl IntoIterator<Item = R>,
) -> Result<String, csv::Error> {
    let text = to_csv(rows)?;
    if text.is_empty() {
        return Ok(format!("{header}\n"));
    }
    debug_assert!(
        text.starts_with(&format!("{header}\n")),
        "the header `{header}` is not the row type's"
    );
    Ok(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Serialize)]
    struct Row {
        name: &'static str,
        #[serde(serialize_with = "sci")]
        x: f64,
        #[serde(serialize_with = "sci_opt")]
        y: Option<f64>,
        #[serde(serialize_with = "display")]
        a: f64,
        #[serde(serialize_with = "fixed::<3, _>")]
        b: f64,
        n: usize,
        ok: bool,
    }

    #[test]
    fn formats_are_the_files() {
        let rows = [
            Row {
                name: "scl, hidden 8",
                x: 0.125,
                y: None,
                a: 1.0,
                b: 0.5,
                n: 3,
                ok: true,
            },
            Row {
                name: "cae",
                x: f64::NAN,
                y: Some(-2e-7),
                a: 0.25,
                b: -1.0 / 3.0,
                n: 0,
                ok: false,
            },
        ];
        assert_eq!(
            to_csv(&rows).unwrap(),
            "name,x,y,a,b,n,ok\n\"scl, hidden 8\",1.250000000e-1,,1,0.500,3,true\n\
             cae,,-2.000000000e-7,0.25,-0.333,0,false\n"
        );
        assert_eq!(to_csv_or_header("name,x", &rows[..0]).unwrap(), "name,x\n");
    }
}
