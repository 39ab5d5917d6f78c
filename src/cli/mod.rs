//! One module per subcommand: its arguments (clap) and the call into the library.
pub mod compare;
pub mod detect;
pub mod export;
pub mod import;
pub mod inspect;
pub mod merge;
pub mod pipeline;
pub mod relax;
pub mod render;
pub mod trace;
