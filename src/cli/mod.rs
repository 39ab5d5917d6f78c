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

/// Refuses, before any work, an output that is one of the command's inputs (opened inputs are
/// registered by the library; the final rename checks again).
pub(crate) fn refuse_input_as_output(output: &str) -> anyhow::Result<()> {
    if output != "-" {
        photonkit::format::guard::check_output(std::path::Path::new(output))?;
    }
    Ok(())
}
