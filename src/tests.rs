//! The command line as the README and the docs print it.

use super::*;
use clap::Parser;
use std::path::Path;

/// The command lines in a markdown text: code-block lines, and with `table_cells` the code spans
/// in a table row's last cell (where the README's figures name their commands; elsewhere
/// `qosrt run` in prose names the command),
/// that start with `qosrt ` or `cargo run --release -- `, as the words qosrt receives (without
/// the `qosrt`), each cut at the shell's `&&`, `|` and `>` and its comments. Templates (`[…]`,
/// `…`, `...`, `a|b`, placeholders in capitals such as `PROFILE`, `SHARD_1.json`, `px4-hil:N`)
/// are left out.
fn command_lines(markdown: &str, table_cells: bool) -> Vec<Vec<String>> {
    let mut candidates: Vec<String> = Vec::new();
    let mut in_block = false;
    for line in markdown.lines() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block;
        } else if in_block {
            candidates.push(line.trim().trim_start_matches("$ ").to_string());
        } else if table_cells && line.starts_with('|') {
            let cells = line.trim_end().trim_end_matches('|');
            let last_cell = cells.rsplit(" | ").next().unwrap_or(cells);
            candidates.extend(last_cell.split('`').skip(1).step_by(2).map(str::to_string));
        }
    }
    let mut lines = Vec::new();
    for text in &candidates {
        let Some(words) = shlex::split(text.split(" # ").next().unwrap_or(text)) else {
            continue;
        };
        for segment in words.split(|w| matches!(w.as_str(), "&&" | "||" | "|" | ";")) {
            let start = if segment.first().is_some_and(|w| w == "qosrt") {
                1
            } else if segment.starts_with(&["cargo", "run", "--release", "--"].map(String::from)) {
                4
            } else {
                continue;
            };
            let words: Vec<String> = segment[start..]
                .iter()
                .take_while(|w| !w.starts_with('>') && !w.starts_with("2>"))
                .cloned()
                .collect();
            let template = |w: &String| {
                w.contains('[') && !w.contains(' ')
                    || w.contains('…')
                    || w.contains("...")
                    || w.starts_with('<')
                    || w.contains('|') && !w.contains(' ')
                    || is_placeholder(w)
            };
            if !words.is_empty() && !words.iter().any(template) {
                lines.push(words);
            }
        }
    }
    lines
}

/// `PROFILE`, `SHARD_1.json`, `F.mcap`, `px4-hil:N`: a word in capitals standing for the user's own.
fn is_placeholder(word: &str) -> bool {
    let stem = word.split('.').next().unwrap_or(word);
    let stem = stem.rsplit(['=', ':']).next().unwrap_or(stem);
    !stem.is_empty()
        && stem
            .chars()
            .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_')
        && stem.chars().any(|c| c.is_ascii_uppercase())
}

fn parse(words: &[&str]) -> Result<Cli, clap::Error> {
    let argv = std::iter::once("qosrt")
        .chain(words.iter().copied())
        .map(OsString::from);
    Cli::try_parse_from(join_optional_values(argv))
}

/// Every command line the README prints (its code blocks and its figures' commands) and every
/// one in the docs' code blocks parses as printed.
#[test]
fn every_command_line_in_the_readme_and_docs_parses_as_printed() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = vec![root.join("README.md")];
    files.extend(
        std::fs::read_dir(root.join("docs"))
            .expect("docs/")
            .map(|entry| entry.expect("a docs entry").path())
            .filter(|path| path.extension().is_some_and(|e| e == "md")),
    );
    let mut checked = 0;
    let mut failures = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(file).expect("a markdown file");
        for words in command_lines(&text, file.ends_with("README.md")) {
            let words: Vec<&str> = words.iter().map(String::as_str).collect();
            checked += 1;
            if let Err(e) = parse(&words) {
                failures.push(format!(
                    "{}: qosrt {}\n{e}",
                    file.display(),
                    words.join(" ")
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // The README alone prints more than twenty command lines; finding fewer means the
    // extraction broke, not that everything parsed.
    assert!(checked > 20, "only {checked} command lines found");
}

#[test]
fn the_config_file_goes_before_or_after_the_optional_value_flags() {
    for words in [
        &["check", "--graph", "configs/precland.toml"][..],
        &["check", "configs/precland.toml", "--graph"],
        &["check", "--graph", "dot", "configs/precland.toml"],
        &["check", "--graph=dot", "configs/precland.toml"],
        &["check", "configs/precland.toml", "--graph-format", "dot"],
    ] {
        let Command::Check {
            file,
            graph,
            graph_format,
            ..
        } = parse(words).unwrap().command
        else {
            panic!("{words:?} is not check");
        };
        assert_eq!(file, Path::new("configs/precland.toml"), "{words:?}");
        let expected = if words.contains(&"dot") || words.contains(&"--graph=dot") {
            check::GraphFormat::Dot
        } else {
            check::GraphFormat::Text
        };
        assert_eq!(graph.or(graph_format), Some(expected), "{words:?}");
    }
    for words in [
        &["sim", "--foxglove", "configs/precland.toml"][..],
        &["sim", "configs/precland.toml", "--foxglove"],
        &["sim", "--foxglove", "0.0.0.0:9000", "configs/precland.toml"],
    ] {
        let Command::Sim(args) = parse(words).unwrap().command else {
            panic!("{words:?} is not sim");
        };
        assert_eq!(args.file, Path::new("configs/precland.toml"), "{words:?}");
        let expected_port = if words.contains(&"0.0.0.0:9000") {
            9000
        } else {
            8765
        };
        assert_eq!(
            args.recording.foxglove.map(|a| a.port()),
            Some(expected_port),
            "{words:?}"
        );
    }
    // A word that is neither a value nor a file is still an error, not silently dropped.
    assert!(parse(&["check", "--graph", "svg", "qos.toml"]).is_err());
}

#[test]
fn command_lines_are_found_and_templates_left_out() {
    let markdown = "```\n$ cargo run --release -- check qos.toml --graph   # the graph\nqosrt model PROFILE --loo\n```\n\
        In prose `qosrt run` names the command.\n\
        | figure | `qosrt sim` in a cell before the last | `qosrt sim --record /tmp/m.mcap && qosrt replay /tmp/m.mcap`, `qosrt plan [qos.toml]` |\n\
        | usage | `qosrt sim --vehicle px4-hil:N`, `qosrt sim --autopilot px4|ardupilot`, `qosrt sim --autopilot-cmd 'start -i {i}'` |";
    let found = command_lines(markdown, true);
    let expected: Vec<Vec<String>> = [
        &["check", "qos.toml", "--graph"][..],
        &["sim", "--record", "/tmp/m.mcap"],
        &["replay", "/tmp/m.mcap"],
        &["sim", "--autopilot-cmd", "start -i {i}"],
    ]
    .iter()
    .map(|words| words.iter().map(|w| w.to_string()).collect())
    .collect();
    assert_eq!(found, expected);
}
