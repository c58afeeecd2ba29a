//! JSON written as Python's `json.dumps` writes it (ASCII only, Python's float repr, keys in insertion order),
//! so that a model file saved from a checkpoint has the bytes the Python converter writes: its `config`
//! metadata is `json.dumps(model_cfg)` and its header `json.dumps(header, separators=(",", ":"))`.

use std::fmt::Write;

use super::pickle::{Id, Node, Pickle, MAX_DEPTH};

/// The most values a config may have (an official run's model section has about 60).
pub const MAX_CONFIG_VALUES: usize = 100_000;

/// `s` as a JSON string with `ensure_ascii`: quotes, backslashes and everything outside space..tilde escaped.
pub fn string(s: &str, out: &mut String) {
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            '\u{8}' => out.push_str("\\b"),
            '\u{c}' => out.push_str("\\f"),
            ' '..='~' => out.push(c),
            _ => {
                let mut units = [0u16; 2];
                for unit in c.encode_utf16(&mut units) {
                    let _ = write!(out, "\\u{unit:04x}");
                }
            }
        }
    }
    out.push('"');
}

/// A finite float as Python's `repr` writes it: the shortest digits that read back, in fixed notation for
/// decimal exponents -4 to 15 (always with a fractional part), else as `d.ddde+XX`.
pub fn float(x: f64, out: &mut String) {
    if x.is_sign_negative() {
        out.push('-');
    }
    let scientific = format!("{:e}", x.abs());
    let (mantissa, exponent) = scientific.split_once('e').expect("{:e} has an exponent");
    let digits: String = mantissa.chars().filter(|c| *c != '.').collect();
    let exponent: i32 = exponent.parse().expect("{:e} has an integer exponent");
    let point = exponent + 1; // digits before the decimal point
    let n = digits.len() as i32;
    if (-3..=16).contains(&point) {
        if point <= 0 {
            let _ = write!(out, "0.{}{digits}", "0".repeat((-point) as usize));
        } else if point >= n {
            let _ = write!(out, "{digits}{}.0", "0".repeat((point - n) as usize));
        } else {
            let _ = write!(out, "{}.{}", &digits[..point as usize], &digits[point as usize..]);
        }
    } else {
        let (first, rest) = digits.split_at(1);
        let fraction = if rest.is_empty() { String::new() } else { format!(".{rest}") };
        let sign = if exponent < 0 { '-' } else { '+' };
        let _ = write!(out, "{first}{fraction}e{sign}{:02}", exponent.abs());
    }
}

/// A dict key as Python's `str` of it (the converter's `str(name)`), or why it cannot be one.
fn key_text(p: &Pickle, id: Id) -> Option<String> {
    Some(match p.node(id) {
        Node::Str(s) => s.clone(),
        Node::Int(v) => v.to_string(),
        Node::Bool(b) => (if *b { "True" } else { "False" }).into(),
        Node::None => "None".into(),
        Node::Float(x) if x.is_finite() => {
            let mut text = String::new();
            float(*x, &mut text);
            text
        }
        _ => return None,
    })
}

/// The config value `id` (at `key`, `depth` levels down) as `json.dumps` of the converter's plain value:
/// dicts (Lightning's AttributeDict and argparse.Namespace read as dicts) with string keys, lists and tuples
/// as lists, strings, numbers, booleans and None; anything else is an error naming its key.
/// `budget` is the number of values left to write: values shared through the pickle's memo are written once
/// per reference, as Python writes them, so a few bytes can stand for exponentially many.
pub fn config(p: &Pickle, id: Id, key: &str, depth: usize, budget: &mut usize, out: &mut String) -> Result<(), String> {
    let at = || if key.is_empty() { "the config".to_string() } else { format!("config value {key}") };
    if depth > MAX_DEPTH {
        return Err(format!("{} is nested more than {MAX_DEPTH} levels deep", at()));
    }
    if *budget == 0 {
        return Err(format!("the config has more than {MAX_CONFIG_VALUES} values"));
    }
    *budget -= 1;
    match p.node(id) {
        Node::None => out.push_str("null"),
        Node::Bool(b) => out.push_str(if *b { "true" } else { "false" }),
        Node::Int(v) => {
            let _ = write!(out, "{v}");
        }
        Node::Float(x) if x.is_finite() => float(*x, out),
        Node::Float(x) => return Err(format!("{} is {}, not a finite number", at(), python_special(*x))),
        Node::Str(s) => string(s, out),
        Node::Dict(_) => {
            out.push('{');
            for (i, (k, v)) in p.dict_items(id).expect("a dict").into_iter().enumerate() {
                let name = key_text(p, k).ok_or_else(|| format!("{} has a key that is {}", at(), p.describe(k)))?;
                if i > 0 {
                    out.push_str(", ");
                }
                string(&name, out);
                out.push_str(": ");
                let inner = if key.is_empty() { name } else { format!("{key}.{name}") };
                config(p, v, &inner, depth + 1, budget, out)?;
            }
            out.push('}');
        }
        Node::List(items) | Node::Tuple(items) => {
            out.push('[');
            for (i, &item) in items.iter().enumerate() {
                if i > 0 {
                    out.push_str(", ");
                }
                config(p, item, &format!("{key}[{i}]"), depth + 1, budget, out)?;
            }
            out.push(']');
        }
        _ => return Err(format!("{} is {}, not a plain config value", at(), p.describe(id))),
    }
    Ok(())
}

fn python_special(x: f64) -> &'static str {
    if x.is_nan() {
        "nan"
    } else if x > 0.0 {
        "inf"
    } else {
        "-inf"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn repr(x: f64) -> String {
        let mut s = String::new();
        float(x, &mut s);
        s
    }

    #[test]
    fn floats_as_python_repr() {
        // Values and what Python's repr() gives for them.
        let cases = [
            (0.0, "0.0"),
            (-0.0, "-0.0"),
            (10.0, "10.0"),
            (0.0001, "0.0001"),
            (1e-5, "1e-05"),
            (1.5e-7, "1.5e-07"),
            (123.456, "123.456"),
            (1e15, "1000000000000000.0"),
            (1e16, "1e+16"),
            (1.2345e22, "1.2345e+22"),
            (0.1 + 0.2, "0.30000000000000004"),
            (-2.5, "-2.5"),
            (5e-324, "5e-324"),
            (1.7976931348623157e308, "1.7976931348623157e+308"),
        ];
        for (x, want) in cases {
            assert_eq!(repr(x), want, "{x:e}");
        }
    }

    #[test]
    fn strings_as_ensure_ascii() {
        let mut s = String::new();
        string("a\"b\\c\n\u{1}é😀\u{7f}~", &mut s);
        assert_eq!(s, r#""a\"b\\c\n\u0001\u00e9\ud83d\ude00\u007f~""#);
    }
}
