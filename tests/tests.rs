//! All integration tests, compiled as one binary so the suite builds fast.
mod suite;
