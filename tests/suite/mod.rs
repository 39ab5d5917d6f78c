pub mod common;
mod format;
mod import;
mod phm_py;
mod relax;
mod render;
mod samples;
mod trace;
mod truth;
