//! No code: this crate only unifies the features of dependencies the `qosrt` binary shares with
//! the test build (see its Cargo.toml).
