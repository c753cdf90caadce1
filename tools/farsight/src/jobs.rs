//! Independent work spread over threads, each result handed back on the
//! caller's thread. The benchmarks' trials are seeded and share nothing, so
//! N of them side by side give the same results about N times sooner on N
//! cores (issue 21, item 1: how many trials an evaluation can afford).

use anyhow::Result;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc;

/// Threads for `items` pieces of work: `asked`, or the machine's cores; at
/// least one, and no more than there are pieces.
pub fn count(asked: Option<usize>, items: usize) -> usize {
    asked.unwrap_or_else(cores).clamp(1, items.max(1))
}

/// The machine's cores (1 where that cannot be read).
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Runs `work(i)` for every `i` in `0..items` on `jobs` threads, handing
/// each result to `done(i, result)` on the calling thread as it comes (in
/// the order the pieces finish, which is `0..items` for one job). The
/// first error, from `work` or `done`, stops new pieces from starting and
/// is returned once the running ones end; their results are dropped.
pub fn run<T: Send>(
    jobs: usize,
    items: usize,
    work: impl Fn(usize) -> Result<T> + Sync,
    mut done: impl FnMut(usize, T) -> Result<()>,
) -> Result<()> {
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        let (tx, rx) = mpsc::channel::<(usize, Result<T>)>();
        for _ in 0..jobs.max(1) {
            let tx = tx.clone();
            let (next, stop, work) = (&next, &stop, &work);
            s.spawn(move || loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= items || stop.load(Ordering::Relaxed) {
                    return;
                }
                let r = work(i);
                let failed = r.is_err();
                if tx.send((i, r)).is_err() || failed {
                    return;
                }
            });
        }
        drop(tx);
        let mut first_error = None;
        for (i, r) in rx {
            if first_error.is_some() {
                continue;
            }
            if let Err(e) = r.and_then(|t| done(i, t)) {
                stop.store(true, Ordering::Relaxed);
                first_error = Some(e);
            }
        }
        first_error.map_or(Ok(()), Err)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    #[test]
    fn every_piece_is_done_once_on_any_number_of_threads() {
        for jobs in [1, 2, 3, 16] {
            let mut seen = Vec::new();
            run(
                jobs,
                25,
                |i| Ok(i * i),
                |i, sq| {
                    assert_eq!(sq, i * i);
                    seen.push(i);
                    Ok(())
                },
            )
            .unwrap();
            if jobs == 1 {
                assert_eq!(seen, (0..25).collect::<Vec<_>>(), "one job keeps the order");
            }
            seen.sort();
            assert_eq!(seen, (0..25).collect::<Vec<_>>(), "{jobs} jobs");
        }
    }

    #[test]
    fn an_error_stops_new_pieces_and_is_returned() {
        let started = Mutex::new(Vec::new());
        let e = run(
            1,
            10,
            |i| {
                started.lock().unwrap().push(i);
                anyhow::ensure!(i != 3, "piece {i} failed");
                Ok(i)
            },
            |_, _| Ok(()),
        )
        .unwrap_err();
        assert_eq!(e.to_string(), "piece 3 failed");
        assert_eq!(*started.lock().unwrap(), vec![0, 1, 2, 3]);
        // An error from the caller's side stops the rest too.
        let mut done = 0;
        let e = run(2, 1000, Ok, |i, _| {
            done += 1;
            anyhow::ensure!(done < 5, "stopped at {i}");
            Ok(())
        })
        .unwrap_err();
        assert!(e.to_string().starts_with("stopped at"), "{e}");
        assert_eq!(done, 5, "no result is handed on after the error");
    }

    #[test]
    fn the_thread_count_is_at_least_one_and_at_most_the_work() {
        assert_eq!(count(Some(8), 3), 3);
        assert_eq!(count(Some(0), 3), 1);
        assert_eq!(count(Some(2), 0), 1);
        assert!(count(None, 1000) >= 1);
    }
}
