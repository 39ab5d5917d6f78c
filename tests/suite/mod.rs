pub mod common;
mod samples;
