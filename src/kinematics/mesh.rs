//! Minimal STL (binary and ASCII) and OBJ readers producing parry `TriMesh`es.
//!
//! Hand-rolled because parry3d-f64 0.25 has no mesh loader and collision meshes need only
//! vertices and triangles; pulling a general asset crate for that would add far more than it saves.

use nalgebra::Point3;
use parry3d_f64::shape::TriMesh;

/// Refuse meshes beyond this many triangles (a collision mesh should be a few thousand).
pub const MAX_TRIANGLES: usize = 2_000_000;

/// Parses `bytes` according to the extension of `filename` and scales the vertices.
pub fn parse_mesh(filename: &str, bytes: &[u8], scale: [f64; 3]) -> Result<TriMesh, String> {
    let ext = filename
        .rsplit('.')
        .next()
        .unwrap_or("")
        .to_ascii_lowercase();
    let (mut vertices, indices) = match ext.as_str() {
        "stl" => parse_stl(bytes)?,
        "obj" => parse_obj(bytes)?,
        other => {
            return Err(format!("mesh format '{other}' is not supported (STL, OBJ)"));
        }
    };
    if indices.is_empty() {
        return Err("mesh has no triangles".into());
    }
    for v in &mut vertices {
        for k in 0..3 {
            v[k] *= scale[k];
        }
        if !v.iter().all(|c| c.is_finite()) {
            return Err("mesh has a non-finite vertex".into());
        }
    }
    TriMesh::new(vertices, indices).map_err(|e| format!("{e:?}"))
}

type Soup = (Vec<Point3<f64>>, Vec<[u32; 3]>);

fn parse_stl(bytes: &[u8]) -> Result<Soup, String> {
    // Binary STL: 80-byte header, u32 count, 50 bytes per facet. Some binary files start with
    // "solid" too, so the size check decides first.
    if bytes.len() >= 84 {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
        if bytes.len() == 84 + 50 * n {
            if n > MAX_TRIANGLES {
                return Err(format!("{n} triangles, over the limit of {MAX_TRIANGLES}"));
            }
            let mut vertices = Vec::with_capacity(3 * n);
            let mut indices = Vec::with_capacity(n);
            for f in 0..n {
                let base = 84 + 50 * f + 12;
                for v in 0..3 {
                    let mut c = [0.0; 3];
                    for (k, ck) in c.iter_mut().enumerate() {
                        let o = base + 12 * v + 4 * k;
                        *ck = f32::from_le_bytes([
                            bytes[o],
                            bytes[o + 1],
                            bytes[o + 2],
                            bytes[o + 3],
                        ]) as f64;
                    }
                    vertices.push(Point3::from(c));
                }
                let i = (3 * f) as u32;
                indices.push([i, i + 1, i + 2]);
            }
            return Ok((vertices, indices));
        }
    }
    let text = std::str::from_utf8(bytes)
        .map_err(|_| "neither binary STL (size mismatch) nor ASCII STL".to_string())?;
    if !text.trim_start().starts_with("solid") {
        return Err("neither binary STL (size mismatch) nor ASCII STL".into());
    }
    let mut vertices = Vec::new();
    for (line_no, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        if it.next() == Some("vertex") {
            let c: Vec<f64> = it
                .map(|t| t.parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|e| format!("line {}: {e}", line_no + 1))?;
            if c.len() != 3 {
                return Err(format!("line {}: vertex needs 3 coordinates", line_no + 1));
            }
            vertices.push(Point3::new(c[0], c[1], c[2]));
        }
    }
    if vertices.len() % 3 != 0 {
        return Err("ASCII STL vertex count is not a multiple of 3".into());
    }
    if vertices.len() / 3 > MAX_TRIANGLES {
        return Err(format!("over the limit of {MAX_TRIANGLES} triangles"));
    }
    let indices = (0..vertices.len() as u32 / 3)
        .map(|f| [3 * f, 3 * f + 1, 3 * f + 2])
        .collect();
    Ok((vertices, indices))
}

fn parse_obj(bytes: &[u8]) -> Result<Soup, String> {
    let text = std::str::from_utf8(bytes).map_err(|_| "OBJ is not UTF-8 text".to_string())?;
    let mut vertices: Vec<Point3<f64>> = Vec::new();
    let mut indices = Vec::new();
    for (line_no, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let c: Vec<f64> = it
                    .take(3)
                    .map(|t| t.parse::<f64>())
                    .collect::<Result<_, _>>()
                    .map_err(|e| format!("line {}: {e}", line_no + 1))?;
                if c.len() != 3 {
                    return Err(format!("line {}: vertex needs 3 coordinates", line_no + 1));
                }
                vertices.push(Point3::new(c[0], c[1], c[2]));
            }
            Some("f") => {
                let mut poly = Vec::new();
                for t in it {
                    // "i", "i/t", "i//n", "i/t/n"; negative indices count from the end.
                    let i: i64 =
                        t.split('/').next().unwrap_or("").parse().map_err(|e| {
                            format!("line {}: bad face index '{t}': {e}", line_no + 1)
                        })?;
                    let idx = if i < 0 {
                        vertices.len() as i64 + i
                    } else {
                        i - 1
                    };
                    if idx < 0 || idx as usize >= vertices.len() {
                        return Err(format!("line {}: face index {i} out of range", line_no + 1));
                    }
                    poly.push(idx as u32);
                }
                if poly.len() < 3 {
                    return Err(format!(
                        "line {}: face with fewer than 3 vertices",
                        line_no + 1
                    ));
                }
                // Fan triangulation: fine for the convex polygons exporters write.
                for k in 1..poly.len() - 1 {
                    indices.push([poly[0], poly[k], poly[k + 1]]);
                }
                if indices.len() > MAX_TRIANGLES {
                    return Err(format!("over the limit of {MAX_TRIANGLES} triangles"));
                }
            }
            _ => {}
        }
    }
    Ok((vertices, indices))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_stl_binary_stl_and_obj_give_the_same_tetrahedron() {
        let p = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ];
        let faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        let mut ascii = String::from("solid t\n");
        let mut bin = vec![0u8; 80];
        bin.extend_from_slice(&(faces.len() as u32).to_le_bytes());
        let mut obj = String::new();
        for v in &p {
            obj += &format!("v {} {} {}\n", v[0], v[1], v[2]);
        }
        for f in &faces {
            ascii += "facet normal 0 0 0\nouter loop\n";
            bin.extend_from_slice(&[0u8; 12]);
            for &i in f {
                ascii += &format!("vertex {} {} {}\n", p[i][0], p[i][1], p[i][2]);
                for c in p[i] {
                    bin.extend_from_slice(&(c as f32).to_le_bytes());
                }
            }
            bin.extend_from_slice(&[0u8; 2]);
            ascii += "endloop\nendfacet\n";
            obj += &format!("f {}/1 {}//2 {}\n", f[0] + 1, f[1] + 1, f[2] + 1);
        }
        ascii += "endsolid t\n";
        for (name, bytes) in [
            ("a.STL", ascii.as_bytes()),
            ("b.stl", &bin[..]),
            ("c.obj", obj.as_bytes()),
        ] {
            let m = parse_mesh(name, bytes, [2.0, 2.0, 2.0]).unwrap();
            assert_eq!(m.num_triangles(), 4, "{name}");
            let aabb = m.local_aabb();
            assert!(
                (aabb.maxs.x - 2.0).abs() < 1e-12 && aabb.mins.x.abs() < 1e-12,
                "{name}"
            );
        }
    }

    #[test]
    fn garbage_and_unsupported_formats_are_rejected() {
        assert!(parse_mesh("x.stl", b"not a mesh", [1.0; 3]).is_err());
        assert!(
            parse_mesh("x.obj", b"v 0 0 0\nf 1 2 3\n", [1.0; 3])
                .unwrap_err()
                .contains("out of range")
        );
        assert!(
            parse_mesh("x.dae", b"<COLLADA/>", [1.0; 3])
                .unwrap_err()
                .contains("not supported")
        );
    }
}
