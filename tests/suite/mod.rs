pub mod common;
mod format;
mod phm_py;
mod relax;
mod samples;
mod trace;
