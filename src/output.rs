//! How every command prints its result: pretty JSON with `--json`, else the text for people.

use serde::Serialize;

/// `value` as pretty JSON (`json`), else `human(value)` as it is.
pub fn print_result<T: Serialize + ?Sized>(
    json: bool,
    value: &T,
    human: impl FnOnce(&T) -> String,
) {
    if json {
        match serde_json::to_string_pretty(value) {
            Ok(text) => println!("{text}"),
            Err(error) => eprintln!("error: cannot write JSON: {error}"),
        }
    } else {
        print!("{}", human(value));
    }
}

/// `value` as pretty JSON.
pub fn print_json<T: Serialize + ?Sized>(value: &T) {
    print_result(true, value, |_| String::new());
}
