//! Transparent huge pages for the closest-point grid's cells.
//!
//! The grid is megabytes of cells read at random: a scan's look-ups land on a few hundred
//! cells spread over the rooms it sees. With 4 KB pages most reads on a large map miss the
//! TLB (the warehouse's 16 MB of cells are 4,000 pages, more than a second-level TLB
//! holds), and under a hypervisor each miss is a two-level page walk. Backed by 2 MB pages
//! the same cells are a few TLB entries: the same cells and answers, fewer page walks (on
//! this project's bench machine, a VM: the warehouse's and the garage's small-start medians
//! about 10-20 % lower). Linux only, and a hint: where transparent huge pages are off
//! (`/sys/kernel/mm/transparent_hugepage/enabled` = `never`: checked once, and then no
//! advice is given at all, since `MADV_COLLAPSE` would otherwise override the admin's
//! choice), or on another OS, the memory is ordinary pages and nothing else changes.

/// Buffers smaller than this are left alone (they hold no whole huge page worth asking for).
const MIN_BYTES: usize = 4 << 20;

/// `n` copies of `value`, in memory the kernel is asked to back with huge pages before it
/// is first written (so that fresh pages fault in as huge pages), and moved into huge
/// pages after (memory the allocator reuses was faulted in before, as small pages).
pub(super) fn filled(n: usize, value: u32) -> Vec<u32> {
    let mut v: Vec<u32> = Vec::with_capacity(n);
    advise(
        v.as_mut_ptr() as usize,
        n * std::mem::size_of::<u32>(),
        false,
    );
    v.resize(n, value);
    collapse(&mut v);
    v
}

/// Ask for huge pages under cells that are already written (cells given by a caller): the
/// kernel then moves them into huge pages at once (`MADV_COLLAPSE`, Linux 6.1 and later;
/// earlier kernels do it in the background).
pub(super) fn collapse(cells: &mut [u32]) {
    advise(
        cells.as_mut_ptr() as usize,
        std::mem::size_of_val(cells),
        true,
    );
}

#[cfg(target_os = "linux")]
fn advise(addr: usize, len: usize, written: bool) {
    const HUGE: usize = 2 << 20;
    /// `MADV_COLLAPSE` (not in every libc's headers)
    const MADV_COLLAPSE: libc::c_int = 25;
    if len < MIN_BYTES || !thp_allowed() {
        return;
    }
    // the whole huge pages inside [addr, addr + len)
    let start = addr.next_multiple_of(HUGE);
    let end = (addr + len) / HUGE * HUGE;
    if end <= start {
        return;
    }
    let p = start as *mut libc::c_void;
    // SAFETY: [start, end) lies inside one live allocation of the caller's; these advices
    // change how the kernel backs those pages, never their contents or validity. A
    // failure (transparent huge pages off, an old kernel) leaves the ordinary pages.
    unsafe {
        libc::madvise(p, end - start, libc::MADV_HUGEPAGE);
        if written {
            libc::madvise(p, end - start, MADV_COLLAPSE);
        }
    }
}

/// Whether the system allows transparent huge pages (its sysfs setting is not `never`;
/// unreadable: allowed, as the kernel's own default is). Read once per process.
#[cfg(target_os = "linux")]
fn thp_allowed() -> bool {
    static ALLOWED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *ALLOWED.get_or_init(|| {
        std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled")
            .map(|s| thp_setting_allows(&s))
            .unwrap_or(true)
    })
}

/// `enabled`'s text (`always [madvise] never`: the bracketed word is the setting) allows
/// huge pages unless the setting is `never`.
#[cfg(any(target_os = "linux", test))]
fn thp_setting_allows(text: &str) -> bool {
    !text.contains("[never]")
}

#[cfg(not(target_os = "linux"))]
fn advise(_addr: usize, _len: usize, _written: bool) {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_never_setting_turns_the_advice_off() {
        assert!(thp_setting_allows("always [madvise] never\n"));
        assert!(thp_setting_allows("[always] madvise never\n"));
        assert!(!thp_setting_allows("always madvise [never]\n"));
    }

    #[test]
    fn filled_and_collapsed_buffers_hold_their_values() {
        for n in [0, 1, 1000, (MIN_BYTES / 4) + 12_345, 3 * (MIN_BYTES / 4)] {
            let mut v = filled(n, 7);
            assert_eq!(v.len(), n);
            assert!(v.iter().all(|&c| c == 7));
            for (i, c) in v.iter_mut().enumerate() {
                *c = i as u32;
            }
            collapse(&mut v);
            assert!(v.iter().enumerate().all(|(i, &c)| c == i as u32));
        }
    }
}
