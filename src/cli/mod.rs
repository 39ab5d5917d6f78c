//! One module per subcommand: its arguments (clap) and the call into the library.
pub mod detect;
pub mod inspect;
pub mod merge;
pub mod pending;
pub mod relax;
pub mod render;
pub mod trace;
