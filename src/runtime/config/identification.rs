//! The `identification` section: the machine's nameplate, as an MES reads it over OPC UA
//! (Machinery's `Identification`: Manufacturer, Model, SerialNumber, ProductInstanceUri,
//! YearOfConstruction).

use serde::Deserialize;

use crate::image::Problem;

/// The longest text a nameplate field takes (characters): an MES shows it on one line.
pub const MAX_FIELD_CHARS: usize = 200;

/// The years of construction accepted (Machinery's YearOfConstruction is a four-digit year).
pub const YEARS: std::ops::RangeInclusive<u16> = 1900..=2200;

/// The machine's nameplate. Every field may be left out: the server then shows what it knows
/// (the machine's model from its name, a product instance URI made of the computer's and the
/// machine's names) and says in its log what is missing.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Identification {
    /// Who built the machine (the lab, a workshop, a vendor).
    #[serde(default)]
    pub manufacturer: Option<String>,
    /// The machine's model, as its manufacturer names it.
    #[serde(default)]
    pub model: Option<String>,
    /// The serial number its manufacturer gave this machine.
    #[serde(default)]
    pub serial_number: Option<String>,
    /// A URI that names this machine and no other, worldwide (`urn:…`, `https://…`).
    #[serde(default)]
    pub product_instance_uri: Option<String>,
    /// The year the machine was built.
    #[serde(default)]
    pub year_of_construction: Option<u16>,
}

impl Identification {
    /// The section's problems, with their paths inside it (`serial_number`).
    pub fn check(&self) -> Vec<Problem> {
        let mut problems = Vec::new();
        let texts = [
            ("manufacturer", &self.manufacturer),
            ("model", &self.model),
            ("serial_number", &self.serial_number),
            ("product_instance_uri", &self.product_instance_uri),
        ];
        for (at, text) in texts {
            let Some(text) = text else { continue };
            let chars = text.chars().count();
            let message = if text.trim().is_empty() {
                "empty: give the value, or leave the field out".to_string()
            } else if chars > MAX_FIELD_CHARS {
                format!("at most {MAX_FIELD_CHARS} characters, got {chars}")
            } else if text.chars().any(char::is_control) {
                "one line of text without control characters".to_string()
            } else {
                continue;
            };
            problems.push(Problem { at: at.into(), message });
        }
        if let Some(uri) = &self.product_instance_uri
            && !uri.trim().is_empty()
            && !is_uri(uri)
        {
            problems.push(Problem {
                at: "product_instance_uri".into(),
                message: format!(
                    "a URI (scheme:rest, without spaces, e.g. urn:example-lab:trijoint:0001), got \"{}\"",
                    super::shorten(uri)
                ),
            });
        }
        if let Some(year) = self.year_of_construction
            && !YEARS.contains(&year)
        {
            problems.push(Problem {
                at: "year_of_construction".into(),
                message: format!("a year {}…{}, got {year}", YEARS.start(), YEARS.end()),
            });
        }
        problems
    }
}

/// Whether `text` has the form of a URI: a scheme (a letter, then letters, digits, `+ - .`), a
/// colon, and something after it, without white space.
fn is_uri(text: &str) -> bool {
    let Some((scheme, rest)) = text.split_once(':') else {
        return false;
    };
    let mut chars = scheme.chars();
    chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
        && !rest.is_empty()
        && !text.chars().any(char::is_whitespace)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn problems(json: &str) -> Vec<(String, String)> {
        let id: Identification = serde_json::from_str(json).expect("parses");
        id.check().into_iter().map(|p| (p.at, p.message)).collect()
    }

    #[test]
    fn a_full_nameplate_passes_and_every_field_may_be_left_out() {
        assert_eq!(
            problems(
                r#"{"manufacturer": "Lab of machine tools", "model": "TRIJOINT 900H lab model",
                    "serial_number": "0001", "product_instance_uri": "urn:example-lab:trijoint:0001",
                    "year_of_construction": 2004}"#
            ),
            vec![]
        );
        assert_eq!(problems("{}"), vec![]);
    }

    #[test]
    fn bad_fields_are_named_with_what_is_expected() {
        assert_eq!(
            problems(
                r#"{"manufacturer": " ", "serial_number": "a\nb", "product_instance_uri": "trijoint 1",
                    "year_of_construction": 204}"#
            ),
            vec![
                (
                    "manufacturer".to_string(),
                    "empty: give the value, or leave the field out".to_string()
                ),
                (
                    "serial_number".to_string(),
                    "one line of text without control characters".to_string()
                ),
                (
                    "product_instance_uri".to_string(),
                    "a URI (scheme:rest, without spaces, e.g. urn:example-lab:trijoint:0001), got \"trijoint 1\""
                        .to_string()
                ),
                (
                    "year_of_construction".to_string(),
                    "a year 1900…2200, got 204".to_string()
                ),
            ]
        );
        let long = format!(r#"{{"model": "{}"}}"#, "x".repeat(201));
        assert_eq!(
            problems(&long),
            vec![("model".to_string(), "at most 200 characters, got 201".to_string())]
        );
    }

    #[test]
    fn unknown_fields_are_refused() {
        let e = serde_json::from_str::<Identification>(r#"{"serial": "1"}"#).expect_err("refused");
        assert!(e.to_string().contains("unknown field `serial`"), "{e}");
    }
}
