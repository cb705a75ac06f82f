//! A laser scan as the points the localizer matches (the localizer's
//! `icploc.scanprep.prepare_scan`): the beams with a usable return, every `decimation`-th
//! of them, as points in the robot frame. The trigonometry of the beam angles is the
//! caller's (computed once per scanner); the products are those of the numpy code this
//! replaces, to the bit.

/// The usable beams of a scan as robot-frame points: a beam is kept when `lo < range < hi`
/// (NaN and inf never are, nor inf at an infinite `hi`) and, with `flags`, none of the
/// `bad` flag bits is set; of those every `decimation`-th from the first. A kept beam `i`
/// is the point `(range cos_i + offset_x, range sin_i + offset_y)`; the offset is added
/// only when one of its components is not zero (`cos`, `sin`: of the beam angles plus the
/// laser's heading on the robot).
#[allow(clippy::too_many_arguments)]
pub fn prepare_points(
    ranges: &[f64],
    flags: Option<&[u8]>,
    cos: &[f64],
    sin: &[f64],
    lo: f64,
    hi: f64,
    decimation: usize,
    bad: u8,
    offset: [f64; 2],
) -> Vec<[f64; 2]> {
    let step = decimation.max(1);
    let shift = offset[0] != 0.0 || offset[1] != 0.0;
    let mut out = Vec::with_capacity(ranges.len() / step + 1);
    let mut kept = 0usize;
    for (i, &r) in ranges.iter().enumerate() {
        let ok = r < hi && r > lo && flags.is_none_or(|f| f[i] & bad == 0);
        if !ok {
            continue;
        }
        kept += 1;
        if (kept - 1) % step != 0 {
            continue;
        }
        let (x, y) = (r * cos[i], r * sin[i]);
        out.push(if shift {
            [x + offset[0], y + offset[1]]
        } else {
            [x, y]
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_usable_beams_and_decimates_them() {
        let r = [1.0, f64::INFINITY, f64::NAN, 0.05, 2.0, 3.0, 30.0, 4.0];
        let c = [1.0; 8];
        let s = [0.5; 8];
        let all = prepare_points(&r, None, &c, &s, 0.1, 25.0, 1, 0, [0.0, 0.0]);
        assert_eq!(all, vec![[1.0, 0.5], [2.0, 1.0], [3.0, 1.5], [4.0, 2.0]]);
        let every2 = prepare_points(&r, None, &c, &s, 0.1, 25.0, 2, 0, [0.0, 0.0]);
        assert_eq!(every2, vec![[1.0, 0.5], [3.0, 1.5]]);
        // a flagged beam is dropped; the offset moves every point
        let flags = [0u8, 0, 0, 0, 4, 1, 0, 0];
        let flagged = prepare_points(&r, Some(&flags), &c, &s, 0.1, 25.0, 1, 4, [0.25, -1.0]);
        assert_eq!(flagged, vec![[1.25, -0.5], [3.25, 0.5], [4.25, 1.0]]);
        // an infinite max range keeps 30 m but never inf
        let open = prepare_points(&r, None, &c, &s, 0.1, f64::INFINITY, 1, 0, [0.0, 0.0]);
        assert_eq!(open.len(), 5);
    }
}
