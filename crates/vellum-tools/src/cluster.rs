//! MPI (issue 27, behind the `mpi` feature): the one module that knows it. [`start`] joins the
//! job when the process was launched by `mpirun`, `mpiexec` or `srun`, and [`MpiTeam`] is the
//! [`Team`] the chunked passes share their work through: agreement on each step's outcome by an
//! all-gather of every rank's sentence, range and count reductions by all-reduce, and rank 0's
//! bytes by broadcast. MPI is called only from the main thread (threading level `Funneled`):
//! the chunk threads of a store never touch it.

use mpi::collective::SystemOperation;
use mpi::datatype::{Partition, PartitionMut};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use mpi::Count;
use vellum_error::{Error, Result};
use vellum_volume::team::Team;

/// Bytes of a rank's sentence in an agreement (longer ones are cut at a character boundary).
const SENTENCE: usize = 1024;

/// The ranks of this MPI job. Dropping it finalises MPI.
pub struct MpiTeam {
    world: SimpleCommunicator,
    // Declared last: finalises MPI after the communicator is gone.
    _universe: mpi::environment::Universe,
}

/// Joins the MPI job this process was launched into, or `None` when MPI was already
/// initialised; an error when MPI does not give the threading the chunk threads need.
pub fn start() -> Result<Option<MpiTeam>> {
    let Some((universe, threading)) = mpi::initialize_with_threading(mpi::Threading::Funneled)
    else {
        return Ok(None);
    };
    if threading == mpi::Threading::Single {
        return Err(Error::Invalid(format!(
            "this MPI gives threading level {threading:?}; vellum's chunk threads need Funneled or more"
        )));
    }
    Ok(Some(MpiTeam {
        world: universe.world(),
        _universe: universe,
    }))
}

impl MpiTeam {
    /// The processor (host) this rank runs on, as MPI names it.
    pub fn host(&self) -> String {
        mpi::environment::processor_name().unwrap_or_default()
    }
}

impl Team for MpiTeam {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }

    fn size(&self) -> usize {
        self.world.size() as usize
    }

    fn agree(&self, outcome: Result<()>) -> Result<()> {
        // Each rank sends one byte (0 ok, 1 failed) and its sentence, zero-padded.
        let mut mine = vec![0u8; 1 + SENTENCE];
        let local = outcome.as_ref().err().map(|e| e.to_string());
        if let Some(text) = &local {
            mine[0] = 1;
            let mut end = text.len().min(SENTENCE);
            while !text.is_char_boundary(end) {
                end -= 1;
            }
            mine[1..1 + end].copy_from_slice(&text.as_bytes()[..end]);
        }
        let mut all = vec![0u8; mine.len() * self.size()];
        self.world.all_gather_into(&mine[..], &mut all[..]);
        let failed = all
            .chunks_exact(mine.len())
            .enumerate()
            .find(|(_, r)| r[0] == 1);
        match failed {
            None => Ok(()),
            Some((rank, r)) => {
                let text = String::from_utf8_lossy(&r[1..]);
                Err(Error::Invalid(format!(
                    "rank {rank} of {} failed: {}",
                    self.size(),
                    text.trim_end_matches('\0')
                )))
            }
        }
    }

    fn min_max(&self, range: [f64; 2]) -> [f64; 2] {
        let (mut lo, mut hi) = (0f64, 0f64);
        self.world
            .all_reduce_into(&range[0], &mut lo, SystemOperation::min());
        self.world
            .all_reduce_into(&range[1], &mut hi, SystemOperation::max());
        [lo, hi]
    }

    fn sum(&self, counts: &mut [u64]) {
        if counts.is_empty() {
            return;
        }
        let mine = counts.to_vec();
        self.world
            .all_reduce_into(&mine[..], counts, SystemOperation::sum());
    }

    fn broadcast(&self, bytes: Vec<u8>) -> Vec<u8> {
        let root = self.world.process_at_rank(0);
        let mut len = bytes.len() as u64;
        root.broadcast_into(&mut len);
        let mut out = if self.rank() == 0 {
            bytes
        } else {
            vec![0u8; len as usize]
        };
        if len > 0 {
            root.broadcast_into(&mut out[..]);
        }
        out
    }

    fn barrier(&self) {
        self.world.barrier();
    }

    fn exchange(
        &self,
        (send, send_counts): (&[f32], &[usize]),
        (recv, recv_counts): (&mut [f32], &[usize]),
    ) {
        let (sc, sd) = counts_and_displacements(send_counts);
        let (rc, rd) = counts_and_displacements(recv_counts);
        let send = Partition::new(send, sc, sd);
        let mut recv = PartitionMut::new(recv, rc, rd);
        self.world.all_to_all_varcount_into(&send, &mut recv);
    }

    fn swap(&self, partner: usize, send: &[f32], recv: &mut [f32]) {
        let p = self.world.process_at_rank(partner as i32);
        mpi::point_to_point::send_receive_into(send, &p, recv, &p);
    }

    fn gather(&self, send: &[f32], counts: &[usize], recv: &mut [f32]) {
        let root = self.world.process_at_rank(0);
        if self.rank() == 0 {
            let (c, d) = counts_and_displacements(counts);
            let mut recv = PartitionMut::new(recv, c, d);
            root.gather_varcount_into_root(send, &mut recv);
        } else {
            root.gather_varcount_into(send);
        }
    }
}

/// MPI's counts and displacements of consecutive parts of `counts` values.
fn counts_and_displacements(counts: &[usize]) -> (Vec<Count>, Vec<Count>) {
    let c: Vec<Count> = counts.iter().map(|&n| n as Count).collect();
    let d = c
        .iter()
        .scan(0, |acc, &n| {
            let at = *acc;
            *acc += n;
            Some(at)
        })
        .collect();
    (c, d)
}
