//! Tests over the bundled robots and the URDF loader's rejections.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix4, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::algorithms::tests::check_jacobian_fd;
use super::*;

pub(crate) fn robots_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("robots")
}

pub(crate) const SYSTEMS: [&str; 6] = [
    "wam_t42",
    "wam_ihy",
    "wam_ob4f",
    "pa10_t42",
    "pa10_ihy",
    "pa10_ob4f",
];

pub(crate) fn load_system(id: &str) -> System {
    System::from_file(&robots_dir().join("systems").join(format!("{id}.toml"))).unwrap()
}

pub(crate) fn random_q_within(model: &Model, rng: &mut ChaCha8Rng) -> Vec<f64> {
    (0..model.nq())
        .map(|k| {
            let (l, u) = (model.lower_limits()[k], model.upper_limits()[k]);
            if l.is_finite() && u.is_finite() && u > l {
                rng.random_range(l..u)
            } else {
                rng.random_range(-3.0..3.0)
            }
        })
        .collect()
}

/// Independent standard-DH forward kinematics: base * Π Rz(θ) Tz(d) Tx(a) Rx(α), as 4x4 matrices.
fn dh_fk(base_z: f64, dh: &[(f64, f64, f64)], q: &[f64]) -> Matrix4<f64> {
    let mut t = Matrix4::identity();
    t[(2, 3)] = base_z;
    for (&(a, alpha, d), &theta) in dh.iter().zip(q) {
        let (ct, st, ca, sa) = (theta.cos(), theta.sin(), alpha.cos(), alpha.sin());
        #[rustfmt::skip]
        let a_i = Matrix4::new(
            ct, -st * ca, st * sa, a * ct,
            st, ct * ca, -ct * sa, a * st,
            0.0, sa, ca, d,
            0.0, 0.0, 0.0, 1.0,
        );
        t *= a_i;
    }
    t
}

#[test]
fn both_arms_match_an_independent_dh_implementation_at_random_configurations() {
    use std::f64::consts::FRAC_PI_2 as H;
    let wam = [
        (0.0, -H, 0.0),
        (0.0, H, 0.0),
        (0.045, -H, 0.55),
        (-0.045, H, 0.0),
        (0.0, -H, 0.3),
        (0.0, H, 0.0),
        (0.0, 0.0, 0.06),
    ];
    let pa10 = [
        (0.0, -H, 0.317),
        (0.0, H, 0.0),
        (0.0, -H, 0.45),
        (0.0, H, 0.0),
        (0.0, -H, 0.48),
        (0.0, H, 0.0),
        (0.0, 0.0, 0.07),
    ];
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for (file, flange, base_z, dh) in [
        ("wam.urdf", "wam_flange", 0.346, &wam),
        ("pa10.urdf", "pa10_flange", 0.0, &pa10),
    ] {
        let model = model_from_urdf_file(&robots_dir().join("arms").join(file)).unwrap();
        assert_eq!(model.nq(), 7);
        let f = model.frame_id(flange).unwrap();
        let mut data = Data::new(&model);
        for _ in 0..200 {
            let q = random_q_within(&model, &mut rng);
            forward_kinematics(&model, &mut data, &q);
            let t = dh_fk(base_z, dh, &q);
            let x = data.frame(f).to_homogeneous();
            let dp = (x.fixed_view::<3, 1>(0, 3) - t.fixed_view::<3, 1>(0, 3)).norm();
            let dr = (x.fixed_view::<3, 3>(0, 0) - t.fixed_view::<3, 3>(0, 0)).norm();
            assert!(
                dp <= 1e-9 && dr <= 1e-9,
                "{file}: position error {dp}, rotation error {dr} at {q:?}"
            );
        }
    }
}

#[test]
fn all_six_systems_load_with_seven_arm_joints_and_their_fingers() {
    for id in SYSTEMS {
        let s = load_system(id);
        assert_eq!(s.arm_joints, (0..7).collect::<Vec<_>>(), "{id}");
        let n_fingers = if id.ends_with("t42") {
            2
        } else if id.ends_with("ihy") {
            3
        } else {
            4
        };
        assert_eq!(s.fingers.len(), n_fingers, "{id}");
        assert_eq!(
            s.spread_pairs.len(),
            usize::from(id.ends_with("ihy")),
            "{id}"
        );
        assert!(!s.hand_joints.is_empty());
        for f in &s.fingers {
            assert!(
                f.joints.iter().all(|j| s.hand_joints.contains(j)),
                "{id}: {}",
                f.name
            );
        }
        // Every link has a collision primitive.
        for j in s.model.joints() {
            let frame = j.child;
            let name = s.model.frame_name(frame);
            let is_link_with_body =
                !name.ends_with("_tip") && !name.ends_with("_flange") && !name.ends_with("_base");
            if is_link_with_body {
                assert!(
                    s.model.collisions().iter().any(|c| c.frame == frame),
                    "{id}: link {name} has no collision"
                );
            }
        }
    }
}

#[test]
fn every_jacobian_of_all_six_systems_matches_central_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for id in SYSTEMS {
        let s = load_system(id);
        for _ in 0..4 {
            let q = random_q_within(&s.model, &mut rng);
            let mut frames: Vec<FrameId> = s.fingers.iter().map(|f| f.tip).collect();
            frames.push(s.wrist_frame);
            frames.extend(&s.elbow_frames);
            for f in frames {
                check_jacobian_fd(&s.model, &q, f, &Vector3::new(0.01, -0.02, 0.03), 1e-6);
            }
        }
    }
}

#[test]
fn mimic_couplings_fold_into_the_proximal_joint() {
    let s = load_system("wam_ihy");
    let m = &s.model;
    let d = m.joint("ihy_finger1_distal").unwrap().actuation.unwrap();
    assert_eq!(d.q_index, m.q_index("ihy_finger1_proximal").unwrap());
    assert!((d.multiplier - 0.7).abs() < 1e-15);
    let sp = m.joint("ihy_finger2_spread").unwrap().actuation.unwrap();
    assert_eq!(sp.q_index, m.q_index("ihy_finger1_spread").unwrap());
    assert_eq!(sp.multiplier, -1.0);
    // 7 arm + spread + 3 proximal: distal and mirrored spread joints are not coordinates.
    assert_eq!(m.nq(), 11);
}

fn combined_wam_t42() -> String {
    let arm = std::fs::read_to_string(robots_dir().join("arms/wam.urdf")).unwrap();
    let hand = std::fs::read_to_string(robots_dir().join("hands/t42.urdf")).unwrap();
    let arm_body = arm.rsplit_once("</robot>").unwrap().0;
    let hand_body = hand.split_once("<robot name=\"openhand_t42\">").unwrap().1;
    format!(
        "{arm_body}<joint name=\"mount\" type=\"fixed\"><parent link=\"wam_flange\"/><child link=\"t42_base\"/></joint>\n{hand_body}"
    )
}

#[test]
fn one_combined_urdf_with_a_descriptor_equals_arm_plus_hand() {
    let separate = load_system("wam_t42");
    let mut desc = separate.descriptor.clone();
    desc.mount = None;
    desc.wrist_frame = Some("t42_base".into());
    let combined =
        System::from_sources(desc, UrdfSources::Combined(&combined_wam_t42()), &NoMeshes).unwrap();
    assert_eq!(combined.model.joint_names(), separate.model.joint_names());
    assert_eq!(combined.arm_joints, separate.arm_joints);
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let (mut d1, mut d2) = (Data::new(&separate.model), Data::new(&combined.model));
    for _ in 0..20 {
        let q = random_q_within(&separate.model, &mut rng);
        forward_kinematics(&separate.model, &mut d1, &q);
        forward_kinematics(&combined.model, &mut d2, &q);
        for (a, b) in separate.fingers.iter().zip(&combined.fingers) {
            assert!(
                (d1.frame(a.tip).translation.vector - d2.frame(b.tip).translation.vector).norm()
                    < 1e-12
            );
        }
    }
}

const ECOSYSTEM: &str = r#"<?xml version="1.0"?>
<robot name="eco">
  <link name="world"/>
  <link name="base"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>
    <collision><geometry><mesh filename="package://eco_description/meshes/base.stl" scale="0.001 0.001 0.001"/></geometry></collision>
    <visual><geometry><mesh filename="package://eco_description/meshes/base.dae"/></geometry></visual></link>
  <link name="l1"><collision><geometry><mesh filename="meshes/l1.obj"/></geometry></collision></link>
  <link name="l2"/>
  <link name="flange"/>
  <link name="tool0"/>
  <link name="finger_l"><collision><geometry><box size="0.01 0.01 0.04"/></geometry></collision></link>
  <link name="finger_r"><collision><geometry><capsule radius="0.005" length="0.03"/></geometry></collision></link>
  <joint name="world_fixed" type="fixed"><parent link="world"/><child link="base"/></joint>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.3"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="1"/></joint>
  <joint name="j2" type="continuous"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.4" rpy="1.5707963 0 0"/><axis xyz="0 0 1"/></joint>
  <joint name="flange_fixed" type="fixed"><parent link="l2"/><child link="flange"/><origin xyz="0.2 0 0"/></joint>
  <joint name="tool_fixed" type="fixed"><parent link="flange"/><child link="tool0"/><origin xyz="0 0 0.05" rpy="0 0 1.57"/></joint>
  <joint name="finger_l_joint" type="prismatic"><parent link="tool0"/><child link="finger_l"/><axis xyz="0 1 0"/><limit lower="0" upper="0.04" effort="20" velocity="0.1"/></joint>
  <joint name="finger_r_joint" type="prismatic"><parent link="tool0"/><child link="finger_r"/><axis xyz="0 -1 0"/><limit lower="0" upper="0.04" effort="20" velocity="0.1"/><mimic joint="finger_l_joint"/></joint>
</robot>"#;

fn write_eco_meshes(dir: &Path) {
    std::fs::create_dir_all(dir.join("meshes")).unwrap();
    let mut stl = vec![0u8; 80];
    stl.extend_from_slice(&1u32.to_le_bytes());
    stl.extend_from_slice(&[0u8; 12]);
    for v in [[0.0f32, 0.0, 0.0], [100.0, 0.0, 0.0], [0.0, 100.0, 0.0]] {
        for c in v {
            stl.extend_from_slice(&c.to_le_bytes());
        }
    }
    stl.extend_from_slice(&[0u8; 2]);
    std::fs::write(dir.join("meshes/base.stl"), stl).unwrap();
    std::fs::write(
        dir.join("meshes/l1.obj"),
        "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    )
    .unwrap();
}

#[test]
fn ordinary_ecosystem_urdfs_load_with_meshes_fixed_tool_frames_and_a_mimic_gripper() {
    let dir = tempfile::tempdir().unwrap();
    write_eco_meshes(dir.path());
    let path = dir.path().join("eco.urdf");
    std::fs::write(&path, ECOSYSTEM).unwrap();
    let model = model_from_urdf_file(&path).unwrap();
    assert_eq!(model.joint_names(), &["j1", "j2", "finger_l_joint"]);
    assert!(
        model.upper_limits()[1].is_infinite(),
        "continuous joint is unbounded"
    );
    assert_eq!(model.collisions().len(), 4);
    let (tool, fl, fr) = (
        model.frame_id("tool0").unwrap(),
        model.frame_id("finger_l").unwrap(),
        model.frame_id("finger_r").unwrap(),
    );
    let mut data = Data::new(&model);
    forward_kinematics(&model, &mut data, &[0.3, -0.2, 0.03]);
    let gap = (data.frame(fl).translation.vector - data.frame(fr).translation.vector).norm();
    assert!(
        (gap - 0.06).abs() < 1e-12,
        "mimic gripper opens symmetrically: {gap}"
    );
    assert!(data.frame(tool).translation.vector.norm() > 0.5);
    check_jacobian_fd(&model, &[0.3, -0.2, 0.03], fr, &Vector3::zeros(), 1e-6);
}

fn reject(urdf: &str) -> KinematicsError {
    model_from_urdf_str(urdf, &NoMeshes).unwrap_err()
}

const TWO_LINKS: &str = r#"<robot name="r"><link name="a"/><link name="b"/>
  <joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
  <origin xyz="ORIGIN"/><limit lower="LOWER" upper="1" effort="1" velocity="1"/></joint></robot>"#;

fn two_links(origin: &str, lower: &str) -> String {
    TWO_LINKS.replace("ORIGIN", origin).replace("LOWER", lower)
}

#[test]
fn urdf_rejections_name_the_joint_or_link() {
    use KinematicsError as E;
    assert!(model_from_urdf_str(&two_links("0 0 1", "-1"), &NoMeshes).is_ok());
    assert!(matches!(
        reject("<robot name=\"x\"><link name=\"a\"></robot>"),
        E::MalformedUrdf { .. }
    ));
    let missing =
        two_links("0 0 1", "-1").replace("<child link=\"b\"/>", "<child link=\"ghost\"/>");
    assert!(
        matches!(reject(&missing), E::MissingLink { joint, link, .. } if joint == "j" && link == "ghost")
    );
    let roots = two_links("0 0 1", "-1")
        .replace("<link name=\"b\"/>", "<link name=\"b\"/><link name=\"c\"/>");
    assert!(
        matches!(reject(&roots), E::SeveralRoots { roots } if roots.contains(&"c".to_string()))
    );
    let cycle = r#"<robot name="r"><link name="a"/><link name="b"/><link name="c"/>
      <joint name="ab" type="fixed"><parent link="a"/><child link="b"/></joint>
      <joint name="bc" type="fixed"><parent link="b"/><child link="c"/></joint>
      <joint name="cb" type="fixed"><parent link="c"/><child link="a"/></joint></robot>"#;
    assert!(matches!(reject(cycle), E::Cycle { .. }));
    let cycle2 = r#"<robot name="r"><link name="a"/><link name="b"/><link name="c"/>
      <joint name="bc" type="fixed"><parent link="b"/><child link="c"/></joint>
      <joint name="cb" type="fixed"><parent link="c"/><child link="b"/></joint></robot>"#;
    assert!(matches!(reject(cycle2), E::Cycle { .. }));
    let mimic = two_links("0 0 1", "-1").replace("</joint>", "<mimic joint=\"nobody\"/></joint>");
    assert!(
        matches!(reject(&mimic), E::MimicUnknownJoint { joint, mimicked } if joint == "j" && mimicked == "nobody")
    );
    assert!(
        matches!(reject(&two_links("0 0 1", "2")), E::LimitsInverted { joint, lower, upper } if joint == "j" && lower == 2.0 && upper == 1.0)
    );
    assert!(
        matches!(reject(&two_links("0 NaN 1", "-1")), E::NonFinite { path, .. } if path.contains("'j'"))
    );
    assert!(
        matches!(reject(&two_links("0 inf 1", "-1")), E::NonFinite { path, .. } if path.contains("'j'"))
    );
    assert!(
        matches!(reject(&two_links("0 0 1", "-inf")), E::NonFinite { path, .. } if path.contains("lower"))
    );
    let geometry = two_links("0 0 1", "-1").replace("<link name=\"b\"/>", "<link name=\"b\"><collision><geometry><sphere radius=\"nan\"/></geometry></collision></link>");
    assert!(matches!(reject(&geometry), E::NonFinite { path, .. } if path.contains("'b'")));
    let mesh = two_links("0 0 1", "-1").replace("<link name=\"b\"/>", "<link name=\"b\"><collision><geometry><mesh filename=\"m.stl\"/></geometry></collision></link>");
    assert!(
        matches!(reject(&mesh), E::MeshUnreadable { link, path, .. } if link == "b" && path == "m.stl")
    );
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("m.stl"), b"garbage").unwrap();
    let garbage = model_from_urdf_str(
        &mesh,
        &DirMeshes {
            base: dir.path().to_path_buf(),
        },
    )
    .unwrap_err();
    assert!(matches!(garbage, E::MeshMalformed { link, .. } if link == "b"));
    let big = format!(
        "<robot name=\"r\"><link name=\"a\"/><!--{}--></robot>",
        "x".repeat(urdf::MAX_URDF_BYTES)
    );
    assert!(matches!(reject(&big), E::UrdfTooLarge { .. }));
    let floating = two_links("0 0 1", "-1").replace("type=\"revolute\"", "type=\"floating\"");
    assert!(matches!(reject(&floating), E::UnsupportedJoint { joint, .. } if joint == "j"));
    let zero_axis = two_links("0 0 1", "-1").replace("xyz=\"0 0 1\"/>", "xyz=\"0 0 0\"/>");
    assert!(matches!(reject(&zero_axis), E::ZeroAxis { joint } if joint == "j"));
}

#[test]
fn descriptor_rejections_name_the_field() {
    use KinematicsError as E;
    let arm = std::fs::read_to_string(robots_dir().join("arms/wam.urdf")).unwrap();
    let hand = std::fs::read_to_string(robots_dir().join("hands/t42.urdf")).unwrap();
    let base = load_system("wam_t42").descriptor;
    let src = || UrdfSources::ArmAndHand {
        arm: &arm,
        hand: &hand,
    };
    let try_with = |f: &dyn Fn(&mut SystemDescriptor)| {
        let mut d = base.clone();
        f(&mut d);
        System::from_sources(d, src(), &NoMeshes).unwrap_err()
    };
    assert!(
        matches!(try_with(&|d| d.mount = None), E::Descriptor { field, .. } if field == "mount")
    );
    assert!(
        matches!(try_with(&|d| d.mount.as_mut().unwrap().parent_frame = "nope".into()), E::UnknownFrame { field, .. } if field == "mount.parent_frame")
    );
    assert!(
        matches!(try_with(&|d| d.mount.as_mut().unwrap().xyz[1] = f64::NAN), E::NonFinite { path, .. } if path == "mount.xyz[1]")
    );
    assert!(
        matches!(try_with(&|d| d.fingers[1].tip_frame = "nope".into()), E::UnknownFrame { field, .. } if field == "fingers[1].tip_frame")
    );
    assert!(
        matches!(try_with(&|d| d.fingers[0].joints.push("ghost".into())), E::UnknownJointInDescriptor { field, name } if field == "fingers[0].joints" && name == "ghost")
    );
    assert!(
        matches!(try_with(&|d| d.fingers[0].contact_radius = -1.0), E::Descriptor { field, .. } if field == "fingers[0].contact_radius")
    );
    assert!(
        matches!(try_with(&|d| d.thumb = "pinky".into()), E::Descriptor { field, .. } if field == "thumb")
    );
    assert!(
        matches!(try_with(&|d| d.elbow_frames.push("x".into())), E::UnknownFrame { field, .. } if field == "elbow_frames[1]")
    );
    assert!(
        matches!(try_with(&|d| d.spread_pairs.push(["a".into(), "b".into()])), E::UnknownJointInDescriptor { field, .. } if field == "spread_pairs[0]")
    );
    assert!(
        matches!(try_with(&|d| d.fingers[0].joints = vec!["wam_joint7".into()]), E::Descriptor { field, .. } if field == "fingers[0].joints")
    );
    let unknown_field = toml::from_str::<SystemDescriptor>("name = \"x\"\nbogus = 1\n");
    assert!(unknown_field.is_err());
}

#[test]
fn visual_geometry_is_kept_beside_the_collision_shapes_and_never_changes_them() {
    use nalgebra::{Quaternion, UnitQuaternion};
    // A unit tetrahedron as OBJ; scaled (2, 3, 4) its far vertices land at x = 2, y = 3, z = 4.
    let tetra = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
    let collision = r#"<collision><origin xyz="0 0 0.1"/><geometry><cylinder radius="0.05" length="0.2"/></geometry></collision>"#;
    let urdf = |visuals: &str| {
        format!(
            r#"<robot name="r"><link name="a"/>
          <link name="b">{collision}{visuals}</link>
          <joint name="j" type="revolute"><parent link="a"/><child link="b"/>
            <origin xyz="0 0 0.3"/><axis xyz="0 0 1"/>
            <limit lower="-1" upper="1" velocity="1" effort="1"/></joint></robot>"#
        )
    };
    let visuals = r#"<visual><origin xyz="0.1 0.2 0.3" rpy="0 0 1.5707963267948966"/>
          <geometry><box size="0.4 0.2 0.1"/></geometry></visual>
        <visual><origin xyz="0 0 -0.05"/>
          <geometry><mesh filename="package://r/meshes/b.obj" scale="2 3 4"/></geometry></visual>"#;
    let meshes = MapMeshes(
        [(
            "package://r/meshes/b.obj".to_owned(),
            tetra.as_bytes().to_vec(),
        )]
        .into_iter()
        .collect(),
    );
    let with = model_from_urdf_str(&urdf(visuals), &meshes).unwrap();
    let without = model_from_urdf_str(&urdf(""), &NoMeshes).unwrap();
    assert!(
        with.visual_errors().is_empty(),
        "{:?}",
        with.visual_errors()
    );
    let b = with.frame_id("b").unwrap();
    let v = with.visuals();
    assert_eq!(v.len(), 2);
    assert!(v.iter().all(|v| v.frame == b));
    // The box: half extents of 0.4 x 0.2 x 0.1, at (0.1, 0.2, 0.3) turned 90° about z:
    // q = (cos 45°, 0, 0, sin 45°).
    let cuboid = v[0].shape.as_cuboid().expect("a box");
    assert!((cuboid.half_extents - Vector3::new(0.2, 0.1, 0.05)).norm() < 1e-12);
    assert!((v[0].origin.translation.vector - Vector3::new(0.1, 0.2, 0.3)).norm() < 1e-12);
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let want = UnitQuaternion::from_quaternion(Quaternion::new(h, 0.0, 0.0, h));
    assert!(v[0].origin.rotation.angle_to(&want) < 1e-9);
    // The mesh: scaled per axis, placed 5 cm down.
    let mesh = v[1].shape.as_trimesh().expect("a mesh");
    assert_eq!(mesh.num_triangles(), 4);
    let aabb = mesh.local_aabb();
    assert!((aabb.maxs.coords - Vector3::new(2.0, 3.0, 4.0)).norm() < 1e-12);
    assert!((v[1].origin.translation.vector - Vector3::new(0.0, 0.0, -0.05)).norm() < 1e-12);
    // Collision shapes, joints and FK are those of the URDF without visuals.
    assert_eq!(with.collisions().len(), 1);
    assert_eq!(without.collisions().len(), 1);
    assert_eq!(with.collisions()[0].origin, without.collisions()[0].origin);
    assert_eq!(
        with.collisions()[0]
            .shape
            .as_cylinder()
            .map(|c| (c.radius, c.half_height)),
        Some((0.05, 0.1))
    );
    assert!(without.visuals().is_empty());
    let (mut da, mut db) = (Data::new(&with), Data::new(&without));
    forward_kinematics(&with, &mut da, &[0.7]);
    forward_kinematics(&without, &mut db, &[0.7]);
    assert_eq!(da.frame(b), db.frame(without.frame_id("b").unwrap()));

    // A visual mesh that is not supplied is kept as an error naming the link and the file
    // (registration refuses it), and the model still loads with its collision shapes.
    let missing = model_from_urdf_str(&urdf(visuals), &NoMeshes).unwrap();
    assert_eq!(missing.visuals().len(), 1, "the box is still kept");
    assert_eq!(missing.collisions().len(), 1);
    assert!(matches!(
        missing.visual_errors(),
        [KinematicsError::MeshUnreadable { link, path, .. }]
            if link == "b" && path == "package://r/meshes/b.obj"
    ));
}
