//! Fast text → numbers for log readers: whitespace-separated floats.

use crate::error::{IcpError, Result};

/// Parse every whitespace-separated token of `text` as an f64 (decimal, exponent, `nan`,
/// `inf`/`infinity`, any case, optional sign), in order, with exact (round-trip) conversion.
/// Any other token is an error naming its position and text.
pub fn parse_floats(text: &str) -> Result<Vec<f64>> {
    let mut out = Vec::with_capacity(text.len() / 6 + 1);
    for (k, tok) in text.split_ascii_whitespace().enumerate() {
        match tok.parse::<f64>() {
            Ok(v) => out.push(v),
            Err(_) => {
                let shown: String = tok.chars().take(40).collect();
                return Err(IcpError::InvalidInput {
                    what: "text".into(),
                    reason: format!("token {k} ({shown:?}) is not a number"),
                });
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_all_forms() {
        let v =
            parse_floats(" 1 -2.5\t3e-2\n.5 5. nan INF -inf +7 1.7976931348623157e308 ").unwrap();
        assert_eq!(v.len(), 10);
        assert_eq!(v[0], 1.0);
        assert_eq!(v[1], -2.5);
        assert_eq!(v[2], 0.03);
        assert_eq!(v[3], 0.5);
        assert_eq!(v[4], 5.0);
        assert!(v[5].is_nan());
        assert_eq!(v[6], f64::INFINITY);
        assert_eq!(v[7], f64::NEG_INFINITY);
        assert_eq!(v[8], 7.0);
        assert_eq!(v[9], f64::MAX);
        assert!(parse_floats("").unwrap().is_empty());
    }

    #[test]
    fn rejects_garbage_with_position() {
        let e = parse_floats("1 2 x3 4").unwrap_err();
        assert!(e.to_string().contains("token 2"), "{e}");
        assert!(parse_floats("1,2").is_err());
        assert!(parse_floats("0x10").is_err());
    }
}
