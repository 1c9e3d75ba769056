//! CSV form of the two sensor streams (one file per stream), for multipart uploads.
//!
//! * Tracker: header `t,shoulder_x,shoulder_y,shoulder_z,elbow_x,elbow_y,elbow_z,wrist_x,wrist_y,
//!   wrist_z,qw,qx,qy,qz`.
//! * Glove: header `t` followed by the 22 channel names of [`GLOVE_CHANNELS`]; values are angles in
//!   radians, or raw sensor values when a calibration is supplied alongside.
//! * Keypoints (instead of the two): header `t`, `<keypoint>_x,_y,_z` for the 21 keypoints of
//!   [`KEYPOINT_NAMES`], optionally `elbow_x..z` and `shoulder_x..z` (both or neither) and
//!   `wrist_qw,wrist_qx,wrist_qy,wrist_qz` (all four or none).
//!
//! Columns are found by header name (order free, extra columns ignored); `#` starts a comment
//! line; blank lines are skipped. The files are plain numeric tables without quoting, so a tiny
//! hand-rolled reader suffices and keeps a CSV crate out of the dependency tree.

use super::demo::{GloveCalibration, GloveStream, KeypointStream, TrackerStream};
use super::error::HumanError;
use super::keypoints::KEYPOINT_NAMES;
use super::model::GLOVE_CHANNELS;

const WRIST_QUATERNION: [&str; 4] = ["wrist_qw", "wrist_qx", "wrist_qy", "wrist_qz"];

/// The keypoint CSV columns, in [`KeypointStream`] order (without the optional quaternion),
/// with or without the arm.
fn keypoint_columns(arm: bool) -> Vec<String> {
    let mut cols = vec!["t".to_string()];
    let arm_points: &[&str] = if arm { &["elbow", "shoulder"] } else { &[] };
    for name in KEYPOINT_NAMES.iter().chain(arm_points) {
        for axis in ["x", "y", "z"] {
            cols.push(format!("{name}_{axis}"));
        }
    }
    cols
}

pub const TRACKER_COLUMNS: [&str; 14] = [
    "t",
    "shoulder_x",
    "shoulder_y",
    "shoulder_z",
    "elbow_x",
    "elbow_y",
    "elbow_z",
    "wrist_x",
    "wrist_y",
    "wrist_z",
    "qw",
    "qx",
    "qy",
    "qz",
];

/// Rows of the requested columns, in the order of `columns`.
fn read_table(
    stream: &'static str,
    text: &str,
    columns: &[&str],
) -> Result<Vec<Vec<f64>>, HumanError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let Some((hline, header)) = lines.next() else {
        return Err(HumanError::EmptyStream { stream });
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let mut idx = Vec::with_capacity(columns.len());
    for c in columns {
        match names.iter().position(|n| n.eq_ignore_ascii_case(c)) {
            Some(i) => idx.push(i),
            None => {
                return Err(HumanError::Csv {
                    stream,
                    line: hline,
                    message: format!("header lacks column `{c}` (expected {})", columns.join(",")),
                });
            }
        }
    }
    let width = names.len();
    let mut rows = Vec::new();
    for (index, (line, l)) in lines.enumerate() {
        let cells: Vec<&str> = l.split(',').map(str::trim).collect();
        if cells.len() != width {
            return Err(HumanError::WrongWidth {
                stream,
                index,
                field: "row".into(),
                expected: width,
                got: cells.len(),
            });
        }
        let mut r = Vec::with_capacity(columns.len());
        for (&i, c) in idx.iter().zip(columns) {
            let v = cells[i].parse::<f64>().map_err(|_| HumanError::Csv {
                stream,
                line,
                message: format!(
                    "column `{c}` (sample {index}): `{}` is not a number",
                    cells[i]
                ),
            })?;
            r.push(v);
        }
        rows.push(r);
    }
    Ok(rows)
}

/// Parse a tracker CSV file.
pub fn parse_tracker_csv(text: &str) -> Result<TrackerStream, HumanError> {
    let rows = read_table("tracker", text, &TRACKER_COLUMNS)?;
    let mut s = TrackerStream::default();
    for r in rows {
        s.t.push(r[0]);
        s.shoulder.push(r[1..4].to_vec());
        s.elbow.push(r[4..7].to_vec());
        s.wrist.push(r[7..10].to_vec());
        s.wrist_orientation.push(r[10..14].to_vec());
    }
    Ok(s)
}

/// Parse a glove CSV file; with a calibration the values are raw sensor readings.
pub fn parse_glove_csv(
    text: &str,
    calibration: Option<GloveCalibration>,
) -> Result<GloveStream, HumanError> {
    let mut cols = vec!["t"];
    cols.extend(GLOVE_CHANNELS);
    let rows = read_table("glove", text, &cols)?;
    let t = rows.iter().map(|r| r[0]).collect();
    let values: Vec<Vec<f64>> = rows.into_iter().map(|mut r| r.split_off(1)).collect();
    Ok(match calibration {
        Some(c) => GloveStream {
            t,
            angles: None,
            raw: Some(values),
            calibration: Some(c),
        },
        None => GloveStream {
            t,
            angles: Some(values),
            raw: None,
            calibration: None,
        },
    })
}

/// Parse a keypoint CSV file.
pub fn parse_keypoint_csv(text: &str) -> Result<KeypointStream, HumanError> {
    let header = text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .unwrap_or("");
    let has = |c: &str| header.split(',').any(|n| n.trim().eq_ignore_ascii_case(c));
    let quaternion = has(WRIST_QUATERNION[0]);
    let arm = has("elbow_x") || has("shoulder_x");
    let mut cols = keypoint_columns(arm);
    if quaternion {
        cols.extend(WRIST_QUATERNION.iter().map(|c| c.to_string()));
    }
    let names: Vec<&str> = cols.iter().map(String::as_str).collect();
    let rows = read_table("keypoints", text, &names)?;
    let mut s = KeypointStream {
        wrist_orientation: quaternion.then(Vec::new),
        elbow: arm.then(Vec::new),
        shoulder: arm.then(Vec::new),
        ..KeypointStream::default()
    };
    let q0 = if arm { 70 } else { 64 };
    for r in rows {
        s.t.push(r[0]);
        s.points
            .push(r[1..64].chunks(3).map(<[f64]>::to_vec).collect());
        if let (Some(e), Some(sh)) = (&mut s.elbow, &mut s.shoulder) {
            e.push(r[64..67].to_vec());
            sh.push(r[67..70].to_vec());
        }
        if let Some(q) = &mut s.wrist_orientation {
            q.push(r[q0..q0 + 4].to_vec());
        }
    }
    Ok(s)
}

/// Keypoint stream as CSV (rows written as they are, so that tests can produce bad files).
pub fn keypoints_to_csv(s: &KeypointStream) -> String {
    let arm = s.elbow.is_some() && s.shoulder.is_some();
    let mut header = keypoint_columns(arm).join(",");
    if s.wrist_orientation.is_some() {
        header.push(',');
        header.push_str(&WRIST_QUATERNION.join(","));
    }
    write_rows(
        &header,
        (0..s.t.len()).map(|i| {
            let mut r = vec![s.t[i]];
            r.extend(s.points.get(i).into_iter().flatten().flatten());
            if arm {
                for col in [&s.elbow, &s.shoulder].into_iter().flatten() {
                    r.extend(col.get(i).into_iter().flatten());
                }
            }
            if let Some(q) = &s.wrist_orientation {
                r.extend(q.get(i).into_iter().flatten());
            }
            r
        }),
    )
}

fn write_rows(header: &str, rows: impl Iterator<Item = Vec<f64>>) -> String {
    let mut out = String::from(header);
    out.push('\n');
    for r in rows {
        let cells: Vec<String> = r.iter().map(|v| format!("{v}")).collect();
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    out
}

/// Tracker stream as CSV (rows are written as they are, even if malformed, so that tests can
/// produce bad files).
pub fn tracker_to_csv(s: &TrackerStream) -> String {
    write_rows(
        &TRACKER_COLUMNS.join(","),
        (0..s.t.len()).map(|i| {
            let mut r = vec![s.t[i]];
            for col in [&s.shoulder, &s.elbow, &s.wrist, &s.wrist_orientation] {
                r.extend(col.get(i).into_iter().flatten());
            }
            r
        }),
    )
}

/// Glove stream as CSV (the `angles`, or the `raw` values when there are no angles).
pub fn glove_to_csv(s: &GloveStream) -> String {
    let values = s.angles.as_ref().or(s.raw.as_ref());
    write_rows(
        &format!("t,{}", GLOVE_CHANNELS.join(",")),
        (0..s.t.len()).map(|i| {
            let mut r = vec![s.t[i]];
            if let Some(v) = values.and_then(|v| v.get(i)) {
                r.extend(v);
            }
            r
        }),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tracker_columns_are_found_by_name_in_any_order() {
        let text = "# Liberty export\nqz,qy,qx,qw,t,wrist_z,wrist_y,wrist_x,elbow_z,elbow_y,elbow_x,\
                    shoulder_z,shoulder_y,shoulder_x,extra\n\
                    0,0,0,1,0.5,3,2,1,6,5,4,9,8,7,99\n";
        let s = parse_tracker_csv(text).unwrap();
        assert_eq!(s.t, vec![0.5]);
        assert_eq!(s.shoulder[0], vec![7.0, 8.0, 9.0]);
        assert_eq!(s.elbow[0], vec![4.0, 5.0, 6.0]);
        assert_eq!(s.wrist[0], vec![1.0, 2.0, 3.0]);
        assert_eq!(s.wrist_orientation[0], vec![1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn csv_round_trips_and_short_rows_are_rejected_with_their_sample_index() {
        let s = TrackerStream {
            t: vec![0.0, 0.1],
            shoulder: vec![vec![0.0, 0.1, 0.2]; 2],
            elbow: vec![vec![0.3, 0.1, 0.2]; 2],
            wrist: vec![vec![0.5, 0.1, 0.2]; 2],
            wrist_orientation: vec![vec![1.0, 0.0, 0.0, 0.0]; 2],
        };
        assert_eq!(parse_tracker_csv(&tracker_to_csv(&s)).unwrap(), s);
        let mut bad = s.clone();
        bad.wrist[1].pop();
        let e = parse_tracker_csv(&tracker_to_csv(&bad)).unwrap_err();
        assert!(
            matches!(
                e,
                HumanError::WrongWidth {
                    stream: "tracker",
                    index: 1,
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn non_numbers_and_missing_columns_name_the_line() {
        let e = parse_tracker_csv("t,qw\n0,1\n").unwrap_err();
        assert!(matches!(e, HumanError::Csv { line: 1, .. }), "{e}");
        let mut header = TRACKER_COLUMNS.join(",");
        header.push_str("\n0,1,2,3,4,5,6,7,8,9,x,0,0,0\n");
        let e = parse_tracker_csv(&header).unwrap_err();
        assert!(matches!(e, HumanError::Csv { line: 2, .. }), "{e}");
        // NaN parses; validation rejects it later with the sample index and field.
        let g = format!(
            "t,{}\n0,{}\n",
            GLOVE_CHANNELS.join(","),
            vec!["NaN"; 22].join(",")
        );
        let s = parse_glove_csv(&g, None).unwrap();
        assert!(s.angles.unwrap()[0][0].is_nan());
    }
}
