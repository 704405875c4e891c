//! Diagnostics that point into a source text: `FILE:LINE:COL: error: MESSAGE` plus the offending
//! line with a caret, the way compilers report mistakes so editors can jump to them.

use serde::Serialize;
use std::fmt::Write as _;
use std::ops::Range;
use std::path::PathBuf;

/// 1-based line and character column of a byte offset; one definition serves config and
/// profile files alike.
pub use power_models::profile::line_col;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Severity {
    Error,
    Warning,
}

/// One finding about a text, located by a byte span (`None` when it concerns the whole file).
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnostic {
    pub severity: Severity,
    pub span: Option<Range<usize>>,
    pub message: String,
}

impl Diagnostic {
    pub fn error(span: Option<Range<usize>>, message: impl Into<String>) -> Self {
        Self {
            severity: Severity::Error,
            span,
            message: message.into(),
        }
    }

    pub fn warning(span: Option<Range<usize>>, message: impl Into<String>) -> Self {
        Self {
            severity: Severity::Warning,
            span,
            message: message.into(),
        }
    }

    /// 1-based line and column (in characters) of the span's start in `source`.
    pub fn line_col(&self, source: &str) -> (usize, usize) {
        line_col(source, self.span.as_ref().map_or(0, |span| span.start))
    }

    /// Renders `FILE:LINE:COL: error: MESSAGE`, then the line and a caret under the span.
    pub fn render(&self, file: &str, source: &str) -> String {
        let (line, column) = self.line_col(source);
        let severity = match self.severity {
            Severity::Error => "error",
            Severity::Warning => "warning",
        };
        let mut out = format!("{file}:{line}:{column}: {severity}: {}\n", self.message);
        if let Some(text) = source.lines().nth(line - 1) {
            let gutter = line.to_string();
            let pad = " ".repeat(gutter.len());
            let span_len = self.span.as_ref().map_or(1, |span| {
                let end = span.end.min(source.len()).max(span.start);
                source
                    .get(span.start..end)
                    .map_or(1, |s| s.lines().next().unwrap_or("").chars().count().max(1))
            });
            let _ = writeln!(out, "{pad} |");
            let _ = writeln!(out, "{gutter} | {text}");
            let _ = writeln!(
                out,
                "{pad} | {}{}",
                " ".repeat(column - 1),
                "^".repeat(span_len)
            );
        }
        out
    }

    /// The diagnostic as a JSON-ready record.
    pub fn to_record(&self, file: &str, source: &str) -> DiagnosticRecord {
        let (line, column) = self.line_col(source);
        DiagnosticRecord {
            file: file.to_string(),
            line,
            column,
            severity: self.severity,
            message: self.message.clone(),
        }
    }
}

/// Diagnostics about one file, with the text they point into.
#[derive(Debug, Clone)]
pub struct FileReport {
    pub path: PathBuf,
    pub source: String,
    pub diagnostics: Vec<Diagnostic>,
}

impl FileReport {
    pub fn render(&self) -> String {
        let file = self.path.display().to_string();
        self.diagnostics
            .iter()
            .map(|diagnostic| diagnostic.render(&file, &self.source))
            .collect()
    }

    pub fn records(&self) -> Vec<DiagnosticRecord> {
        let file = self.path.display().to_string();
        self.diagnostics
            .iter()
            .map(|diagnostic| diagnostic.to_record(&file, &self.source))
            .collect()
    }

    pub fn has_errors(&self) -> bool {
        self.diagnostics
            .iter()
            .any(|diagnostic| diagnostic.severity == Severity::Error)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DiagnosticRecord {
    pub file: String,
    pub line: usize,
    pub column: usize,
    pub severity: Severity,
    pub message: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn render_puts_the_caret_under_the_span() {
        let text = "[mission]\nname = 42\n";
        let start = text.find("42").unwrap();
        let diagnostic = Diagnostic::error(Some(start..start + 2), "expected a string");
        let rendered = diagnostic.render("qos.toml", text);
        let lines: Vec<&str> = rendered.lines().collect();
        assert_eq!(lines[0], "qos.toml:2:8: error: expected a string");
        assert_eq!(lines[2], "2 | name = 42");
        assert_eq!(lines[3], "  |        ^^");
    }
}
