//! What a stage process holds in memory (issue 21 item 7), from Linux's
//! `/proc/<pid>/smaps`: its private memory (USS: pages only it maps, the
//! Private_Clean and Private_Dirty of every mapping) without shared
//! memory, and apart from that the shared memory it maps (resident pages
//! of `/dev/shm` files, System V segments and memfds: iceoryx2's sample
//! pools and queues). A `/dev/shm` pool that only one process has touched
//! counts as private to the kernel; it is shared memory here, because
//! another stage can map it at any time and it is sized by the graph, not
//! the stage.

use std::fmt;

/// A process's memory, bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ProcessMemory {
    /// Pages only this process maps, shared memory excluded.
    pub private_bytes: u64,
    /// Resident pages of the shared memory it maps.
    pub shared_memory_bytes: u64,
}

impl fmt::Display for ProcessMemory {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{:.1} MB private, {:.1} MB shared memory",
            mb(self.private_bytes),
            mb(self.shared_memory_bytes)
        )
    }
}

pub fn mb(bytes: u64) -> f64 {
    bytes as f64 / (1024.0 * 1024.0)
}

/// Whether a mapping's path is shared memory.
fn is_shared_memory(path: &str) -> bool {
    path.starts_with("/dev/shm/") || path.starts_with("/SYSV") || path.starts_with("/memfd:")
}

/// Sums an `smaps` text (see `proc(5)`).
pub fn parse_smaps(text: &str) -> ProcessMemory {
    let mut m = ProcessMemory::default();
    let mut shared = false;
    for line in text.lines() {
        let mut fields = line.split_whitespace();
        let Some(first) = fields.next() else {
            continue;
        };
        if !first.ends_with(':') {
            // A mapping's header: range perms offset dev inode [path].
            let path = line.split_whitespace().nth(5).unwrap_or("");
            shared = is_shared_memory(path);
            continue;
        }
        let mut kb = || {
            fields
                .next()
                .and_then(|v| v.parse::<u64>().ok())
                .unwrap_or(0)
                * 1024
        };
        match (first, shared) {
            ("Private_Clean:" | "Private_Dirty:", false) => m.private_bytes += kb(),
            ("Rss:", true) => m.shared_memory_bytes += kb(),
            _ => {}
        }
    }
    m
}

/// The memory of process `pid`, if it runs on this machine and is
/// readable.
pub fn of_pid(pid: u32) -> Option<ProcessMemory> {
    std::fs::read_to_string(format!("/proc/{pid}/smaps"))
        .ok()
        .map(|t| parse_smaps(&t))
}

/// Process `pid` on this machine is a farsight process: health reports
/// carry the pid, but a laptop's process with the robot stage's pid is
/// someone else.
pub fn is_local_farsight_process(pid: u32) -> bool {
    std::fs::read(format!("/proc/{pid}/cmdline")).is_ok_and(|c| {
        c.split(|&b| b == 0)
            .next()
            .is_some_and(|exe| String::from_utf8_lossy(exe).contains("farsight"))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMAPS: &str = "\
56403e2f7000-56403e2f9000 r--p 00000000 fe:00 247282                     /usr/bin/farsight-inference
Size:                  8 kB
Rss:                   8 kB
Private_Clean:         8 kB
Private_Dirty:         0 kB
VmFlags: rd mr mw me
7f0000000000-7f0000400000 rw-p 00000000 00:00 0
Size:               4096 kB
Rss:                3000 kB
Private_Clean:         0 kB
Private_Dirty:      3000 kB
VmFlags: rd wr mr mw me ac
7f1000000000-7f1000600000 rw-s 00000000 00:19 1234                       /dev/shm/iox2_abc.data_segment
Size:               6144 kB
Rss:                6144 kB
Private_Clean:         0 kB
Private_Dirty:      6144 kB
VmFlags: rd wr sh mr mw me ms
7f2000000000-7f2000001000 rw-s 00000000 00:01 99                         /memfd:queue (deleted)
Size:                  4 kB
Rss:                   4 kB
Private_Dirty:         4 kB
";

    #[test]
    fn private_memory_leaves_out_shared_memory_even_when_only_this_process_touched_it() {
        let m = parse_smaps(SMAPS);
        assert_eq!(m.private_bytes, (8 + 3000) * 1024);
        assert_eq!(m.shared_memory_bytes, (6144 + 4) * 1024);
        assert_eq!(m.to_string(), "2.9 MB private, 6.0 MB shared memory");
        assert_eq!(parse_smaps(""), ProcessMemory::default());
    }

    #[test]
    fn this_process_reads_its_own_memory_with_an_allocation_in_it() {
        // Other tests share the process and may free memory meanwhile, so
        // the check is absolute: 64 MB written is at least 64 MB private.
        let pid = std::process::id();
        let block = vec![1u8; 64 << 20];
        let m = of_pid(pid).expect("own smaps");
        assert!(m.private_bytes >= 64 << 20, "{m}");
        drop(std::hint::black_box(block));
        assert_eq!(of_pid(u32::MAX), None);
        // The test binary is target/<profile>/deps/farsight-<hash>.
        assert!(is_local_farsight_process(pid));
        assert!(!is_local_farsight_process(u32::MAX));
    }
}
