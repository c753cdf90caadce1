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
/// the order the pieces finish, which is `0..items` for one job). A piece
/// that fails or panics stops new pieces from starting; the ones running
/// finish and their results are still handed on (nothing finished is
/// lost), unless `done` itself failed. The error returned is the one of
/// the lowest-numbered piece that failed (or `done`'s), whatever the
/// threads' timing.
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
                if stop.load(Ordering::SeqCst) {
                    return;
                }
                let i = next.fetch_add(1, Ordering::SeqCst);
                if i >= items {
                    return;
                }
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| work(i)))
                    .unwrap_or_else(|panic| {
                        let why = panic
                            .downcast_ref::<&str>()
                            .map(|s| s.to_string())
                            .or_else(|| panic.downcast_ref::<String>().cloned())
                            .unwrap_or_else(|| "a panic".into());
                        Err(anyhow::anyhow!("piece {i} panicked: {why}"))
                    });
                if r.is_err() {
                    stop.store(true, Ordering::SeqCst);
                }
                if tx.send((i, r)).is_err() {
                    return;
                }
            });
        }
        drop(tx);
        let mut first_error: Option<(usize, anyhow::Error)> = None;
        let mut done_failed = false;
        for (i, r) in rx {
            let failed = match r {
                Ok(t) if !done_failed => match done(i, t) {
                    Ok(()) => None,
                    Err(e) => {
                        done_failed = true;
                        stop.store(true, Ordering::SeqCst);
                        Some(e)
                    }
                },
                Ok(_) => None,
                Err(e) => Some(e),
            };
            if let Some(e) = failed {
                if first_error.as_ref().is_none_or(|(j, _)| i < *j) {
                    first_error = Some((i, e));
                }
            }
        }
        first_error.map_or(Ok(()), |(_, e)| Err(e))
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
        let e = run(1, 1000, Ok, |i, _| {
            done += 1;
            anyhow::ensure!(done < 5, "stopped at {i}");
            Ok(())
        })
        .unwrap_err();
        assert_eq!(e.to_string(), "stopped at 4");
        assert_eq!(done, 5, "no result is handed on after the caller's error");
    }

    #[test]
    fn a_panic_is_an_error_naming_its_piece() {
        let e = run(
            1,
            5,
            |i| {
                if i == 2 {
                    panic!("bad world {i}")
                } else {
                    Ok(i)
                }
            },
            |_, _| Ok(()),
        )
        .unwrap_err();
        assert_eq!(e.to_string(), "piece 2 panicked: bad world 2");
    }

    #[test]
    fn side_by_side_the_lowest_failure_is_returned_and_finished_work_is_kept() {
        use std::sync::atomic::AtomicBool;
        let wait_for = |flag: &AtomicBool| {
            while !flag.load(Ordering::SeqCst) {
                std::thread::yield_now();
            }
        };
        for zero_fails in [false, true] {
            // Piece 0 starts, then piece 1 fails, then piece 0 ends: its
            // result is still handed on, or, failing too, its error is the
            // one returned (the lowest piece, not the first to fail).
            let (zero_started, one_failed) = (AtomicBool::new(false), AtomicBool::new(false));
            let mut kept = Vec::new();
            let e = run(
                2,
                2,
                |i| {
                    if i == 0 {
                        zero_started.store(true, Ordering::SeqCst);
                        wait_for(&one_failed);
                        anyhow::ensure!(!zero_fails, "piece 0 failed");
                        return Ok(0);
                    }
                    wait_for(&zero_started);
                    one_failed.store(true, Ordering::SeqCst);
                    anyhow::bail!("piece 1 failed")
                },
                |i, _| {
                    kept.push(i);
                    Ok(())
                },
            )
            .unwrap_err();
            if zero_fails {
                assert_eq!(e.to_string(), "piece 0 failed");
                assert!(kept.is_empty());
            } else {
                assert_eq!(e.to_string(), "piece 1 failed");
                assert_eq!(kept, vec![0]);
            }
        }
    }

    #[test]
    fn the_thread_count_is_at_least_one_and_at_most_the_work() {
        assert_eq!(count(Some(8), 3), 3);
        assert_eq!(count(Some(2), 0), 1);
        assert!(count(None, 1000) >= 1);
    }
}
