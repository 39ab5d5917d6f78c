pub mod common;
mod samples;
mod phm_py;
mod relax;
mod trace;
mod render;
