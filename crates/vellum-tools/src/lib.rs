//! The tools of the `vellum` binary, kept out of the library and the Python extension: the
//! benchmarks ([`bench`](mod@bench)), the papers' figures ([`figures`]), the fuzz harness ([`fuzz`]), the
//! showcase page ([`showcase`]) and, behind the `mpi` feature, the MPI ranks (`cluster`), which
//! nothing beneath imports.

pub mod bench;
#[cfg(feature = "mpi")]
pub mod cluster;
pub mod figures;
pub mod fuzz;
pub mod showcase;
