use glam::{DQuat, DVec3};

use super::*;

#[test]
fn the_lightest_joints_merge_into_their_parents_until_the_cap() {
    // 0 ─┬─ 1 ─┬─ 2
    //    │     └─ 3
    //    └─ 4
    let parents = [None, Some(0), Some(1), Some(1), Some(0)];
    let weights = [10, 5, 1, 2, 3];
    assert_eq!(merge(&parents, &weights, &[], 3), vec![0, 1, 1, 1, 4]);
    assert_eq!(merge(&parents, &weights, &[], 0), vec![0, 1, 2, 3, 4]);
    assert_eq!(merge(&parents, &weights, &[], 1), vec![0; 5]);
}

#[test]
fn chains_without_vertices_never_get_a_joint() {
    let parents = [None, Some(0), Some(1)];
    // The middle chain has no geometry; its child keeps a joint of its own,
    // hung under the root chain's.
    let top = merge(&parents, &[4, 0, 2], &[], 0);
    assert_eq!(top, vec![0, 0, 2]);
    let (joint_of, joint_parents, tops) = order_joints(&parents, &top, &[4, 0, 2]);
    assert_eq!(joint_parents, vec![None, Some(0), Some(1)]);
    assert_eq!(tops, vec![None, Some(0), Some(2)]);
    assert_eq!(joint_of[2], 2);
}

fn cloud() -> Vec<DVec3> {
    (0..40)
        .map(|i| {
            let x = i as f64;
            DVec3::new((x * 0.37).sin(), x * 0.1, (x * 0.71).cos() * 0.5)
        })
        .collect()
}

#[test]
fn a_similarity_is_recovered_from_its_points() {
    let p = cloud();
    let truth = Similarity {
        scale: 0.6,
        rotation: DQuat::from_euler(glam::EulerRot::XYZ, 0.4, -1.1, 0.3),
        translation: DVec3::new(1.0, 2.0, -3.0),
    };
    let q: Vec<DVec3> = p.iter().map(|&x| truth.apply(x)).collect();
    let fit = fit(&p, q.iter().copied(), DQuat::IDENTITY, 40).unwrap();
    assert!((fit.scale - truth.scale).abs() < 1e-6, "{fit:?}");
    assert!(
        fit.rotation.dot(truth.rotation).abs() > 1.0 - 1e-6,
        "{fit:?}"
    );
    assert!(
        fit.translation.distance(truth.translation) < 1e-6,
        "{fit:?}"
    );
    let back = fit.inverse().then_after(&fit);
    assert!(back.apply(DVec3::ONE).distance(DVec3::ONE) < 1e-9);
}

#[test]
fn a_collapsed_joint_shrinks_to_its_junction_without_spinning() {
    let p = cloud();
    let turned = DQuat::from_rotation_y(0.8);
    let junction = DVec3::new(0.5, 1.0, 0.0);
    let grown: Vec<DVec3> = p.iter().map(|&x| turned * x).collect();
    let fits = vec![
        fit(
            &p,
            std::iter::repeat_n(junction, p.len()),
            DQuat::IDENTITY,
            40,
        ),
        fit(&p, grown.iter().copied(), DQuat::IDENTITY, 40),
    ];
    assert!(fits[0].is_err());
    let filled = fill_degenerate(&fits);
    assert_eq!(filled[0].scale, MIN_SCALE);
    assert!(filled[0].rotation.dot(turned).abs() > 1.0 - 1e-9);
    let centre = p.iter().copied().sum::<DVec3>() / p.len() as f64;
    assert!(filled[0].apply(centre).distance(junction) < 1e-9);
}

#[test]
fn chains_that_grow_while_their_parent_holds_still_merge_last() {
    // 0 ─┬─ 1 (grows late)
    //    └─ 2 (steady, heavier)
    let parents = [None, Some(0), Some(0)];
    let steady = vec![1.0, 1.0, 1.0];
    let profiles = [steady.clone(), vec![0.0, 0.2, 1.0], steady];
    assert_eq!(merge(&parents, &[10, 4, 6], &profiles, 2), vec![0, 1, 0]);
    assert_eq!(merge(&parents, &[10, 4, 6], &[], 2), vec![0, 0, 2]);
}
