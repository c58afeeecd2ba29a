use thiserror::Error;

/// Everything that can be wrong with a model or scene file. Each message names the file and the tensor
/// or key, what was expected and what was found.
#[derive(Debug, Error)]
pub enum ModelError {
    #[error("{path}: cannot read: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: not a valid safetensors file: {reason}")]
    Format { path: String, reason: String },
    #[error("{path}: checkpoint: {reason}")]
    Checkpoint { path: String, reason: String },
    #[error("{path}: config: {reason}")]
    Config { path: String, reason: String },
    #[error("{path}: missing tensor `{key}` (expected shape {expected:?})")]
    Missing { path: String, key: String, expected: Vec<usize> },
    #[error("{path}: unexpected tensor `{key}` with shape {found:?} (not part of this model)")]
    Unexpected { path: String, key: String, found: Vec<usize> },
    #[error("{path}: tensor `{key}` has shape {found:?}, expected {expected:?}")]
    Shape { path: String, key: String, expected: Vec<usize>, found: Vec<usize> },
    #[error("{path}: tensor `{key}` has dtype {found}, expected F32")]
    Dtype { path: String, key: String, found: String },
    #[error("{path}: tensor `{key}`: {reason}")]
    Value { path: String, key: String, reason: String },
}

/// The most characters of a value from the user (a matrix, a list, a flag's text) that a message quotes.
pub const MAX_QUOTED_CHARS: usize = 80;

/// The most characters of a whole one-line message: what a surface (the CLI's stderr, a Python exception, a
/// server's error response) passes on at most, whatever an error quotes.
pub const MAX_MESSAGE_CHARS: usize = 2000;

/// A value as an error message quotes it: whole when short, else its first [`MAX_QUOTED_CHARS`] characters
/// and its length, so that a huge input (a 50 MB camera matrix) never comes back whole. Formatting it does
/// not build the whole text of the value.
///
/// ```
/// use raypatch_model::error::Quoted;
/// assert_eq!(Quoted("[1, 2]").to_string(), "[1, 2]");
/// let long = "9".repeat(1000);
/// assert_eq!(Quoted(&long).to_string(), format!("{}... (1000 characters)", "9".repeat(80)));
/// ```
pub struct Quoted<T>(pub T);

impl<T: std::fmt::Display> std::fmt::Display for Quoted<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        bounded(f, format_args!("{}", self.0))
    }
}

/// `{:?}` quotes the value's debug form (a string in quotes) the same way.
impl<T: std::fmt::Debug> std::fmt::Debug for Quoted<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        bounded(f, format_args!("{:?}", self.0))
    }
}

/// Writes the first [`MAX_QUOTED_CHARS`] characters of `value` and, if there are more, how many in all.
fn bounded(f: &mut std::fmt::Formatter<'_>, value: std::fmt::Arguments<'_>) -> std::fmt::Result {
    /// Keeps the first characters written to it and counts the rest.
    struct Head {
        kept: String,
        chars: usize,
    }
    impl std::fmt::Write for Head {
        fn write_str(&mut self, s: &str) -> std::fmt::Result {
            for c in s.chars() {
                if self.chars < MAX_QUOTED_CHARS {
                    self.kept.push(c);
                }
                self.chars += 1;
            }
            Ok(())
        }
    }
    let mut head = Head { kept: String::new(), chars: 0 };
    std::fmt::write(&mut head, value)?;
    if head.chars <= MAX_QUOTED_CHARS {
        f.write_str(&head.kept)
    } else {
        write!(f, "{}... ({} characters)", head.kept, head.chars)
    }
}

/// `message` on one line of at most [`MAX_MESSAGE_CHARS`] characters: line breaks become spaces, and the
/// middle of a longer message is left out (its start names the file or flag, its end what was expected).
pub fn one_line(message: &str) -> String {
    let line = message.replace(['\r', '\n'], " ");
    let chars = line.chars().count();
    if chars <= MAX_MESSAGE_CHARS {
        return line;
    }
    let keep = (MAX_MESSAGE_CHARS - 40) / 2;
    let head: String = line.chars().take(keep).collect();
    let tail: String = line.chars().skip(chars - keep).collect();
    format!("{head} ... ({} characters left out) ... {tail}", chars - 2 * keep)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quotes_and_messages_are_bounded() {
        assert_eq!(Quoted(12.5).to_string(), "12.5");
        assert_eq!(format!("{:?}", Quoted("a")), "\"a\"");
        let huge = "1.0, ".repeat(100_000);
        let quoted = Quoted(&huge).to_string();
        assert!(quoted.len() < 120 && quoted.ends_with("(500000 characters)"), "{quoted}");
        assert_eq!(Quoted("é".repeat(81)).to_string(), format!("{}... (81 characters)", "é".repeat(80)));
        let message = format!("pose.json: `transform_matrix` is {huge}, expected a 4x4 matrix");
        let line = one_line(&message);
        assert!(line.chars().count() <= MAX_MESSAGE_CHARS, "{}", line.len());
        assert!(line.starts_with("pose.json: ") && line.ends_with("expected a 4x4 matrix"), "{line}");
        assert_eq!(one_line("a\nb"), "a b");
    }
}
