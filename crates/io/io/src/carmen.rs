//! CARMEN laser logs (the Carnegie Mellon Robot Navigation Toolkit's logger format, as used by
//! the Radish / Freiburg 2D laser datasets): one message per line, every message ending with
//! `ipc_timestamp ipc_hostname logger_timestamp`.
//!
//! Read: `PARAM`, `ODOM`, `FLASER`/`RLASER` (old front/rear laser), `ROBOTLASER1`/`2`
//! (laser with its configuration and both poses), `RAWLASER1`–`4` (laser without a pose).
//! Every other tag (`NEFF`, `TRUEPOS`, `SYNC`, …) is counted in
//! [`LaserLog::skipped_messages`]. Written: `PARAM`, `ODOM`, `ROBOTLASER1` (scans with a pose)
//! and `RAWLASER1` (scans without). See `docs/formats.md` for the field layouts and the
//! max-range rule for `FLASER`/`RLASER`, which carry no maximum range.

use core::f64::consts::{FRAC_PI_2, PI};
use std::collections::BTreeMap;
use std::path::Path;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::{LaserLog, LaserScan, OdometryReading, ScanRecord};

use crate::input::read_text;
use crate::reader::{
    data_lines, parse_count, parse_error, parse_f32, parse_f64, parse_f64s, quoted, se2, LineResult,
};
use crate::writer::{push_f32, push_f64, push_id, save};
use crate::IoError;

/// Host name written into the trailing `ipc_timestamp host logger_timestamp` of each message.
const HOST: &str = "mapmerge";

/// The `PARAM` that gives the maximum range of `FLASER` scans (m).
pub const FRONT_LASER_MAX_PARAM: &str = "robot_front_laser_max";

/// The `PARAM` that gives the maximum range of `RLASER` scans (m).
pub const REAR_LASER_MAX_PARAM: &str = "robot_rear_laser_max";

/// Max-range rule: readings within this distance (m) of the next larger distinct reading
/// belong to the same cluster. Saturated readings jitter by a few centimetres (51.05–51.16,
/// 81.87–81.91, 32.759–32.767 in the public logs); real long returns are sparser.
const SATURATION_GAP_M: f64 = 0.06;

/// Max-range rule: the saturation cluster spans at most this far (m) below the largest
/// reading, so dense real returns cannot pull the limit far down.
const SATURATION_WINDOW_M: f64 = 1.0;

/// Max-range rule: the cluster must hold at least this fraction of all readings of that laser
/// to count as the sensor's "no return" value.
const SATURATION_MIN_FRACTION: f64 = 0.001;

/// Max-range rule: and this many times as many readings as the 1 m band just below it
/// (saturation piles readings onto a few values; real returns thin out smoothly).
const SATURATION_CONTRAST: usize = 10;

/// Max-range rule: and at least this many readings (one or two large readings of a short log
/// are not evidence of saturation).
const SATURATION_MIN_READINGS: usize = 3;

/// Max-range rule: a PARAM is overruled when more than this fraction of all readings lie
/// above it but below the saturation cluster.
const PARAM_CONTRADICTION_FRACTION: f64 = 0.01;

/// Max-range rule: the limit when the readings show no saturation cluster (m): a SICK LMS at
/// its 80 m setting.
const FALLBACK_MAX_RANGE_M: f32 = 80.0;

/// Reads a CARMEN log (plain or xz-compressed, recognised by its magic bytes).
pub fn read_carmen(path: &Path) -> Result<LaserLog, IoError> {
    let text = read_text(path)?;
    parse_carmen(&text, &path.display().to_string())
}

/// Which laser of the old `FLASER`/`RLASER` pair a scan came from.
#[derive(Clone, Copy, PartialEq, Eq)]
enum OldLaser {
    Front,
    Rear,
}

/// What the line handlers collect.
#[derive(Default)]
struct LogBuilder {
    log: LaserLog,
    /// Indices into `log.scans` of `FLASER` scans, whose max range is set at the end.
    front: Vec<usize>,
    /// Same for `RLASER`.
    rear: Vec<usize>,
    /// Line of the last `PARAM` line of each name.
    param_lines: BTreeMap<String, usize>,
}

/// Parses the text of a CARMEN log; `source` names it in errors.
///
/// Malformed lines of the messages listed in the module doc (wrong field count, a count `n`
/// that does not match the line, non-numeric or non-finite numbers) are
/// [`IoError::Parse`] errors; unknown tags are counted in `skipped_messages`.
pub fn parse_carmen(text: &str, source: &str) -> Result<LaserLog, IoError> {
    let mut builder = LogBuilder::default();
    let mut tokens: Vec<&str> = Vec::new();
    for line in data_lines(text) {
        tokens.clear();
        tokens.extend(line.fields.rest());
        let tag = line.tag;
        let handled = match tag {
            "PARAM" => builder.param(&tokens, line.number),
            "ODOM" => parse_odom(&tokens).map(|odom| builder.log.odometry.push(odom)),
            "FLASER" => builder.old_laser(tag, &tokens, OldLaser::Front),
            "RLASER" => builder.old_laser(tag, &tokens, OldLaser::Rear),
            "ROBOTLASER1" | "ROBOTLASER2" => {
                parse_laser(tag, &tokens, true).map(|record| builder.log.scans.push(record))
            }
            "RAWLASER1" | "RAWLASER2" | "RAWLASER3" | "RAWLASER4" => {
                parse_laser(tag, &tokens, false).map(|record| builder.log.scans.push(record))
            }
            _ => {
                *builder
                    .log
                    .skipped_messages
                    .entry(tag.to_owned())
                    .or_default() += 1;
                Ok(())
            }
        };
        handled.map_err(|reason| parse_error(source, line.number, reason))?;
    }
    builder.apply_max_range(OldLaser::Front, source)?;
    builder.apply_max_range(OldLaser::Rear, source)?;
    Ok(builder.log)
}

impl LogBuilder {
    /// `PARAM name value …`: anything after the value (the trailing stamps, in whatever form
    /// old loggers wrote them) is ignored.
    fn param(&mut self, tokens: &[&str], line: usize) -> LineResult<()> {
        let [name, value, ..] = tokens else {
            return Err(format!(
                "truncated PARAM line: expected a name and a value after the tag, found {} \
                 field(s)",
                tokens.len()
            ));
        };
        self.log
            .params
            .insert((*name).to_owned(), (*value).to_owned());
        self.param_lines.insert((*name).to_owned(), line);
        Ok(())
    }

    /// `FLASER`/`RLASER n r1 … rn x y θ odom_x odom_y odom_θ ts host ts`.
    fn old_laser(&mut self, tag: &str, tokens: &[&str], which: OldLaser) -> LineResult<()> {
        let n_token = tokens.first().ok_or_else(|| {
            format!("truncated {tag} line: expected the beam count after the tag")
        })?;
        let n = parse_count(n_token, 1, "beam count")?;
        // n ranges, two poses, the trailing stamps.
        let expected = n
            .checked_add(1 + 6 + 3)
            .ok_or_else(|| format!("field 1: beam count {} is too large", quoted(n_token)))?;
        check_count(tag, tokens.len(), expected, &format!(" (n = {n})"))?;
        let ranges_m = parse_ranges(tokens, 1, n)?;
        let [lx, ly, lt] = parse_f64s::<3>(tokens, n + 1)?;
        let [rx, ry, rt] = parse_f64s::<3>(tokens, n + 4)?;
        let stamp_secs = parse_stamps(tokens, n + 7)?;
        let (laser, robot) = (se2(lx, ly, lt), se2(rx, ry, rt));
        let scan = LaserScan {
            angle_min_rad: -FRAC_PI_2,
            angle_increment_rad: old_laser_increment_rad(n),
            range_min_m: 0.0,
            // Set by `apply_max_range` once all scans and PARAMs are read.
            range_max_m: FALLBACK_MAX_RANGE_M,
            ranges_m,
            robot_from_sensor: sensor_offset(&robot, &laser),
        };
        let list = match which {
            OldLaser::Front => &mut self.front,
            OldLaser::Rear => &mut self.rear,
        };
        list.push(self.log.scans.len());
        self.log.scans.push(ScanRecord {
            stamp_secs,
            scan,
            odom_from_robot: Some(robot),
            source_tag: tag.to_owned(),
        });
        Ok(())
    }

    /// Sets the max range of every `FLASER` (or `RLASER`) scan ([`old_laser_max_range_m`] of
    /// their readings and the log's PARAM).
    fn apply_max_range(&mut self, which: OldLaser, file: &str) -> Result<(), IoError> {
        let (indices, param) = match which {
            OldLaser::Front => (&self.front, FRONT_LASER_MAX_PARAM),
            OldLaser::Rear => (&self.rear, REAR_LASER_MAX_PARAM),
        };
        if indices.is_empty() {
            return Ok(());
        }
        let scans = &mut self.log.scans;
        let param_m = match self.log.params.get(param) {
            Some(value) => match fast_float2::parse::<f32, _>(value) {
                Ok(v) if v.is_finite() && v > 0.0 => Some(v),
                _ => {
                    let line = self.param_lines.get(param).copied().unwrap_or(0);
                    let reason = format!(
                        "PARAM {param} {} is not a positive number of metres",
                        quoted(value)
                    );
                    return Err(parse_error(file, line, reason));
                }
            },
            None => None,
        };
        let readings = indices
            .iter()
            .filter_map(|&i| scans.get(i))
            .flat_map(|record| record.scan.ranges_m.iter().copied());
        let range_max_m = old_laser_max_range_m(readings, param_m);
        for &i in indices {
            if let Some(record) = scans.get_mut(i) {
                record.scan.range_max_m = range_max_m;
            }
        }
        Ok(())
    }
}

/// Angle between the beams of an old-style laser (`FLASER`/`RLASER`): `n` beams over 180°,
/// the first at −90°. Odd `n` (181, 361) has beams at both ends: π/(n − 1); even `n` (180,
/// 360) stops one step short of +90°: π/n. Fewer than two beams: π.
pub fn old_laser_increment_rad(n: usize) -> f64 {
    match n {
        0 | 1 => PI,
        n if n % 2 == 1 => PI / (n - 1) as f64,
        n => PI / n as f64,
    }
}

/// The maximum range (m) of an old-style laser (`FLASER`/`RLASER`), from all its readings in
/// the log and the log's `robot_front_laser_max`/`robot_rear_laser_max` PARAM, if any.
///
/// 1. **Saturation cluster.** Saturated ("no return") readings form a dense cluster at the
///    top of the readings, a few centimetres wide (51.05–51.16, 81.87–81.91, 32.759–32.767
///    in the public logs). Starting from the largest reading, readings are added in
///    decreasing order while each is within 0.06 m of the previous one and within 1 m of the
///    largest. The cluster counts if it holds at least 0.1 % of all readings, at least 3, and
///    at least 10 times as many as the 1 m band just below it.
/// 2. **PARAM.** The PARAM value is used unless the readings contradict it: when it lies
///    above the cluster (saturated readings would count as returns), or when more than 1 % of
///    all readings lie above it but below the cluster (real returns would be thrown
///    away; edmonton's PARAM says 10 m while 30 % of its readings lie between 10 m and its
///    51.1 m saturation value).
/// 3. Otherwise the smallest reading of the cluster is the maximum range (every reading of
///    the cluster counts as no return).
/// 4. Without a cluster the log has no saturated readings: 80 m (a SICK LMS at its 80 m
///    setting), raised to just above the largest reading when that reaches 80 m, so no
///    reading is declared "no return" without evidence. No readings at all: 80 m.
pub fn old_laser_max_range_m(
    readings: impl Iterator<Item = f32> + Clone,
    param_m: Option<f32>,
) -> f32 {
    let finite = readings.filter(|r| r.is_finite());
    let total = finite.clone().count();
    let cluster = saturation_cluster(finite.clone(), total);
    if let Some(param) = param_m {
        let above_cluster = cluster.is_some_and(|low| param > low);
        let cut = finite
            .clone()
            .filter(|&r| r > param && cluster.is_none_or(|low| r < low))
            .count();
        if !above_cluster && cut as f64 <= PARAM_CONTRADICTION_FRACTION * total as f64 {
            return param;
        }
    }
    if let Some(low) = cluster {
        return low;
    }
    match finite.reduce(f32::max) {
        Some(top) if (FALLBACK_MAX_RANGE_M..f32::MAX).contains(&top) => {
            // The next f32 above a positive finite `top`.
            f32::from_bits(top.to_bits() + 1)
        }
        Some(top) if top >= FALLBACK_MAX_RANGE_M => top,
        _ => FALLBACK_MAX_RANGE_M,
    }
}

/// The smallest reading of the saturation cluster (step 1 of [`old_laser_max_range_m`]), if
/// the readings have one; `total` is their number.
fn saturation_cluster(finite: impl Iterator<Item = f32> + Clone, total: usize) -> Option<f32> {
    let top = finite.clone().reduce(f32::max)?;
    let floor = f64::from(top) - SATURATION_WINDOW_M;
    let mut near: Vec<f32> = finite.clone().filter(|&r| f64::from(r) >= floor).collect();
    near.sort_by(|a, b| b.total_cmp(a));
    near.dedup();
    let mut low = top;
    for &r in near.iter().skip(1) {
        if f64::from(low) - f64::from(r) > SATURATION_GAP_M {
            break;
        }
        low = r;
    }
    let count = finite.clone().filter(|&r| r >= low).count();
    let band_floor = f64::from(low) - SATURATION_WINDOW_M;
    let below = finite
        .filter(|&r| r < low && f64::from(r) >= band_floor)
        .count();
    let counts = count >= SATURATION_MIN_READINGS
        && count as f64 >= SATURATION_MIN_FRACTION * total as f64
        && count >= below.saturating_mul(SATURATION_CONTRAST);
    counts.then_some(low)
}

/// `robot⁻¹ · laser`, exactly the identity when the two poses are equal.
fn sensor_offset(robot: &Se2, laser: &Se2) -> Se2 {
    if robot == laser {
        Se2::identity()
    } else {
        robot.between(laser)
    }
}

/// Rejects a line with `found` fields after the tag when it needs `expected`.
fn check_count(tag: &str, found: usize, expected: usize, detail: &str) -> LineResult<()> {
    if found < expected {
        Err(format!(
            "truncated {tag} line: expected {expected} fields after the tag{detail}, found {found}"
        ))
    } else if found > expected {
        Err(format!(
            "too many fields on {tag} line: expected {expected} after the tag{detail}, found \
             {found}"
        ))
    } else {
        Ok(())
    }
}

/// `n` ranges from `tokens[start..start + n]` (bounds already checked).
fn parse_ranges(tokens: &[&str], start: usize, n: usize) -> LineResult<Vec<f32>> {
    let slice = tokens
        .get(start..start.saturating_add(n))
        .ok_or_else(|| format!("missing field {}", start + 1))?;
    slice
        .iter()
        .enumerate()
        .map(|(k, token)| parse_f32(token, start + k + 1))
        .collect()
}

/// Checks `count` numbers from `tokens[start..]` (remissions, velocities) without keeping them.
fn check_numbers(tokens: &[&str], start: usize, count: usize) -> LineResult<()> {
    for index in start..start.saturating_add(count) {
        let token = tokens
            .get(index)
            .ok_or_else(|| format!("missing field {}", index + 1))?;
        parse_f64(token, index + 1)?;
    }
    Ok(())
}

/// The trailing `ipc_timestamp host logger_timestamp` at `tokens[start..]`; returns the IPC
/// timestamp. The host may be any token.
fn parse_stamps(tokens: &[&str], start: usize) -> LineResult<f64> {
    let [ipc] = parse_f64s::<1>(tokens, start)?;
    parse_f64s::<1>(tokens, start + 2)?;
    Ok(ipc)
}

/// `ODOM x y θ tv rv accel ts host ts`.
fn parse_odom(tokens: &[&str]) -> LineResult<OdometryReading> {
    check_count("ODOM", tokens.len(), 9, "")?;
    let [x, y, theta, tv, rv, _accel] = parse_f64s::<6>(tokens, 0)?;
    Ok(OdometryReading {
        stamp_secs: parse_stamps(tokens, 6)?,
        odom_from_robot: se2(x, y, theta),
        velocity_m_per_s: tv,
        turn_rate_rad_per_s: rv,
    })
}

/// `ROBOTLASERk` (`with_poses`) or `RAWLASERk`:
/// `laser_type start_angle fov angular_res max_range accuracy remission_mode n r1 … rn
/// n_rem rem1 … [laser_x laser_y laser_θ robot_x robot_y robot_θ tv rv forward_safety
/// side_safety turn_axis] ts host ts`.
fn parse_laser(tag: &str, tokens: &[&str], with_poses: bool) -> LineResult<ScanRecord> {
    // After the ranges and remissions: (two poses, five robot fields,) three stamp fields.
    let trailer = if with_poses { 6 + 5 + 3 } else { 3 };
    let config = 7;
    let at_least = config + 2 + trailer;
    if tokens.len() <= config {
        return Err(format!(
            "truncated {tag} line: expected at least {at_least} fields after the tag, found {}",
            tokens.len()
        ));
    }
    let n = parse_count(
        tokens.get(config).copied().unwrap_or_default(),
        8,
        "beam count",
    )?;
    let n_rem_index = (config + 1)
        .checked_add(n)
        .ok_or_else(|| "field 8: beam count is too large".to_owned())?;
    let Some(n_rem_token) = tokens.get(n_rem_index) else {
        return Err(format!(
            "truncated {tag} line: expected at least {} fields after the tag (n = {n}), found {}",
            at_least.saturating_add(n),
            tokens.len()
        ));
    };
    let n_rem = parse_count(n_rem_token, n_rem_index + 1, "remission count")?;
    let expected = (n_rem_index + 1)
        .checked_add(n_rem)
        .and_then(|e| e.checked_add(trailer))
        .ok_or_else(|| format!("field {}: remission count is too large", n_rem_index + 1))?;
    check_count(
        tag,
        tokens.len(),
        expected,
        &format!(" (n = {n}, n_remissions = {n_rem})"),
    )?;
    let [_laser_type, start_angle, _fov, angular_res] = parse_f64s::<4>(tokens, 0)?;
    let range_max_m = parse_f32(tokens.get(4).copied().unwrap_or_default(), 5)?;
    parse_f64s::<2>(tokens, 5)?;
    let ranges_m = parse_ranges(tokens, config + 1, n)?;
    let rest = n_rem_index + 1;
    check_numbers(tokens, rest, n_rem)?;
    let rest = rest + n_rem;
    let (odom_from_robot, robot_from_sensor, stamp_at) = if with_poses {
        let [lx, ly, lt] = parse_f64s::<3>(tokens, rest)?;
        let [rx, ry, rt] = parse_f64s::<3>(tokens, rest + 3)?;
        check_numbers(tokens, rest + 6, 5)?;
        let (laser, robot) = (se2(lx, ly, lt), se2(rx, ry, rt));
        (Some(robot), sensor_offset(&robot, &laser), rest + 11)
    } else {
        (None, Se2::identity(), rest)
    };
    Ok(ScanRecord {
        stamp_secs: parse_stamps(tokens, stamp_at)?,
        scan: LaserScan {
            angle_min_rad: start_angle,
            angle_increment_rad: angular_res,
            range_min_m: 0.0,
            range_max_m,
            ranges_m,
            robot_from_sensor,
        },
        odom_from_robot,
        source_tag: tag.to_owned(),
    })
}

/// An [`IoError::Unwritable`] for CARMEN output.
fn unwritable(reason: String) -> IoError {
    IoError::Unwritable {
        format: "CARMEN",
        reason,
    }
}

/// Appends ` ts mapmerge ts` and the newline.
fn push_stamps(out: &mut String, stamp_secs: f64) {
    push_f64(out, stamp_secs);
    out.push(' ');
    out.push_str(HOST);
    push_f64(out, stamp_secs);
    out.push('\n');
}

fn push_pose(out: &mut String, pose: &Se2) {
    for v in [pose.x_m, pose.y_m, pose.theta_rad] {
        push_f64(out, v);
    }
}

/// Appends one `ODOM` line.
fn push_odom(out: &mut String, index: usize, odom: &OdometryReading) -> Result<(), IoError> {
    let numbers = [
        odom.stamp_secs,
        odom.odom_from_robot.x_m,
        odom.odom_from_robot.y_m,
        odom.odom_from_robot.theta_rad,
        odom.velocity_m_per_s,
        odom.turn_rate_rad_per_s,
    ];
    if numbers.iter().any(|v| !v.is_finite()) {
        return Err(unwritable(format!(
            "odometry reading {index} has a non-finite number"
        )));
    }
    out.push_str("ODOM");
    push_pose(out, &odom.odom_from_robot);
    push_f64(out, odom.velocity_m_per_s);
    push_f64(out, odom.turn_rate_rad_per_s);
    out.push_str(" 0");
    push_stamps(out, odom.stamp_secs);
    Ok(())
}

/// Appends one `ROBOTLASER1` (scan with a pose) or `RAWLASER1` (without) line.
fn push_scan(out: &mut String, index: usize, record: &ScanRecord) -> Result<(), IoError> {
    let scan = &record.scan;
    let n = scan.ranges_m.len();
    let fov_rad = scan.angle_increment_rad * n.saturating_sub(1) as f64;
    let laser = record.odom_from_robot.map(|robot| {
        if scan.robot_from_sensor == Se2::identity() {
            robot
        } else {
            robot.compose(&scan.robot_from_sensor)
        }
    });
    let finite_poses = record
        .odom_from_robot
        .iter()
        .chain(laser.iter())
        .chain([&scan.robot_from_sensor])
        .all(Se2::is_finite);
    let finite = [
        record.stamp_secs,
        scan.angle_min_rad,
        scan.angle_increment_rad,
        fov_rad,
    ]
    .iter()
    .all(|v| v.is_finite())
        && scan.range_max_m.is_finite()
        && scan.ranges_m.iter().all(|r| r.is_finite())
        && finite_poses;
    if !finite {
        return Err(unwritable(format!("scan {index} has a non-finite number")));
    }
    if record.odom_from_robot.is_none() && scan.robot_from_sensor != Se2::identity() {
        return Err(unwritable(format!(
            "scan {index} has a sensor offset but no robot pose (RAWLASER1 cannot carry it)"
        )));
    }
    out.push_str(if laser.is_some() {
        "ROBOTLASER1 0"
    } else {
        "RAWLASER1 0"
    });
    push_f64(out, scan.angle_min_rad);
    push_f64(out, fov_rad);
    push_f64(out, scan.angle_increment_rad);
    push_f32(out, scan.range_max_m);
    // accuracy, remission mode, n.
    out.push_str(" 0 0");
    push_id(out, n as u64);
    for &r in &scan.ranges_m {
        push_f32(out, r);
    }
    // No remissions.
    out.push_str(" 0");
    if let (Some(laser), Some(robot)) = (laser, record.odom_from_robot) {
        push_pose(out, &laser);
        push_pose(out, &robot);
        // tv rv forward_safety side_safety turn_axis.
        out.push_str(" 0 0 0 0 0");
    }
    push_stamps(out, record.stamp_secs);
    Ok(())
}

/// The text of `log` as a CARMEN log: `PARAM` lines (name order), then `ODOM` and scan lines
/// merged by stamp (odometry first on equal stamps; each list keeps its own order, so
/// non-monotone stamps merge greedily). Scans with a pose are written as `ROBOTLASER1`
/// (laser pose = robot pose · sensor offset), scans without as `RAWLASER1`.
///
/// Reading the text back gives `log` again, except `source_tag` (`ROBOTLASER1`/`RAWLASER1`),
/// `skipped_messages` (empty), `range_min_m` (not stored; reads back 0) and sensor offsets
/// other than the identity (recomputed from the two poses, equal to about 1e-15).
/// Non-finite numbers, parameters that are empty or contain whitespace, and a sensor offset
/// on a scan without a pose are [`IoError::Unwritable`].
pub fn format_carmen(log: &LaserLog) -> Result<String, IoError> {
    let beams: usize = log.scans.iter().map(|r| r.scan.ranges_m.len()).sum();
    let mut out = String::with_capacity(
        log.params.len() * 64 + log.odometry.len() * 96 + log.scans.len() * 192 + beams * 6,
    );
    for (name, value) in &log.params {
        // What the reader splits on (ASCII whitespace) cannot be inside a word.
        let bad = |s: &str| s.is_empty() || s.bytes().any(|b| b.is_ascii_whitespace());
        if bad(name) || bad(value) {
            return Err(unwritable(format!(
                "PARAM {} {} must be two non-empty words",
                quoted(name),
                quoted(value)
            )));
        }
        out.push_str("PARAM ");
        out.push_str(name);
        out.push(' ');
        out.push_str(value);
        push_stamps(&mut out, 0.0);
    }
    let (mut i, mut j) = (0, 0);
    loop {
        match (log.odometry.get(i), log.scans.get(j)) {
            (Some(odom), Some(record)) if odom.stamp_secs <= record.stamp_secs => {
                push_odom(&mut out, i, odom)?;
                i += 1;
            }
            (Some(odom), None) => {
                push_odom(&mut out, i, odom)?;
                i += 1;
            }
            (_, Some(record)) => {
                push_scan(&mut out, j, record)?;
                j += 1;
            }
            (None, None) => break,
        }
    }
    Ok(out)
}

/// Writes `log` to `path` as a CARMEN log (see [`format_carmen`]), xz-compressed when the path
/// ends in `.xz`.
pub fn write_carmen(path: &Path, log: &LaserLog) -> Result<(), IoError> {
    save(path, &format_carmen(log)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn old_laser_increments() {
        let deg = 1f64.to_radians();
        assert_eq!(old_laser_increment_rad(180), deg);
        assert_eq!(old_laser_increment_rad(181), deg);
        assert_eq!(old_laser_increment_rad(360), deg / 2.0);
        assert_eq!(old_laser_increment_rad(361), deg / 2.0);
        assert_eq!(old_laser_increment_rad(1), PI);
        assert_eq!(old_laser_increment_rad(0), PI);
    }

    #[test]
    fn max_range_finds_the_saturation_cluster() {
        // 1000 readings: a jittery cluster at 51.05–51.16 (2 %), returns up to 10.45 m.
        let mut r: Vec<f32> = (0..980).map(|k| 0.5 + (k % 200) as f32 * 0.05).collect();
        r.extend([
            51.16, 51.15, 51.15, 51.12, 51.1, 51.1, 51.08, 51.07, 51.06, 51.05,
        ]);
        r.extend([51.15; 10]);
        let max = |param| old_laser_max_range_m(r.iter().copied(), param);
        assert_eq!(max(None), 51.05);
        // A PARAM below the cluster with few readings in between is kept …
        assert_eq!(max(Some(50.5)), 50.5);
        // … one that would throw away many returns, or make saturated readings returns, not.
        assert_eq!(max(Some(10.0)), 51.05);
        assert_eq!(max(Some(60.0)), 51.05);
        // No cluster: a single large reading is a return.
        let sparse: Vec<f32> = (0..1000).map(|k| k as f32 * 0.03).collect();
        assert_eq!(old_laser_max_range_m(sparse.iter().copied(), None), 80.0);
        assert_eq!(
            old_laser_max_range_m(sparse.iter().copied(), Some(100.0)),
            100.0
        );
        assert_eq!(
            old_laser_max_range_m(sparse.iter().copied(), Some(5.0)),
            80.0
        );
        let far: Vec<f32> = (0..1000).map(|k| k as f32 * 0.1).collect();
        let far_top = far.iter().copied().fold(0.0, f32::max);
        let limit = old_laser_max_range_m(far.iter().copied(), None);
        assert!(
            far_top > 80.0 && limit > far_top && limit < far_top + 1e-4,
            "{limit}"
        );
        assert_eq!(old_laser_max_range_m(core::iter::empty(), None), 80.0);
        assert_eq!(old_laser_max_range_m(core::iter::empty(), Some(30.0)), 30.0);
        // Two equal large readings in a short log are not a cluster; three are.
        assert_eq!(
            old_laser_max_range_m([1.0, 2.0, 9.0, 9.0].into_iter(), None),
            80.0
        );
        assert_eq!(
            old_laser_max_range_m([1.0, 9.0, 9.0, 9.0].into_iter(), None),
            9.0
        );
    }

    #[test]
    fn equal_poses_give_an_exact_identity_offset() {
        let p = Se2::new(0.600266, -0.0320327, -0.354665);
        assert_eq!(sensor_offset(&p, &p), Se2::identity());
        let q = Se2::new(0.7, -0.0320327, -0.354665);
        let offset = sensor_offset(&p, &q);
        assert!(offset != Se2::identity());
        let back = p.compose(&offset);
        assert!((back.x_m - q.x_m).abs() < 1e-15 && (back.y_m - q.y_m).abs() < 1e-15);
    }
}
