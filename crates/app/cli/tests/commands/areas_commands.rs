//! Integration tests of `mapmerge areas` and `mapmerge route` on a simulated session.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common::{ok_json, p, run, scratch};

#[test]
fn areas_splits_a_session_at_its_doors_and_routes_between_them() {
    let dir = scratch("areas-sim");
    let report = ok_json(&[
        "areas",
        "--sim",
        "office",
        "--seed",
        "1",
        "--duration",
        "90",
        "-o",
        p(&dir),
        "--json",
    ]);
    let areas = report["areas"].as_u64().unwrap();
    assert!(areas >= 2, "{report}");
    assert!(report["link_points"].as_u64().unwrap() >= 1, "{report}");
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("areas.json")).unwrap()).unwrap();
    assert_eq!(file["areas"].as_array().unwrap().len() as u64, areas);
    for area in file["areas"].as_array().unwrap() {
        let sub = dir.join(area["dir"].as_str().unwrap());
        for name in [
            "graph.g2o",
            "map.yaml",
            "map.pgm",
            "map.png",
            "trajectory.tum",
        ] {
            assert!(sub.join(name).is_file(), "{}", sub.join(name).display());
        }
        assert!(["indoor", "large"].contains(&area["config"].as_str().unwrap()));
    }
    assert!(dir.join("overview.png").is_file());
    for passing in file["door_passings"].as_array().unwrap() {
        assert_eq!(passing["session"].as_u64(), Some(0));
    }
    // From the first area to the last: through every link point in between, in order.
    let last = areas - 1;
    let route = ok_json(&[
        "route",
        p(&dir),
        "--from",
        "0:0,0",
        "--to",
        &format!("{last}:0.5,0.5"),
        "--json",
    ]);
    let route = &route["route"];
    assert_eq!(route["areas"].as_array().unwrap().first().unwrap(), 0);
    assert_eq!(
        route["areas"].as_array().unwrap().last().unwrap().as_u64(),
        Some(last)
    );
    assert!(route["length_m"].as_f64().unwrap() > 0.0);
    // Bad input: an unknown area, a malformed place.
    assert_eq!(
        run(&["route", p(&dir), "--from", "0:0,0", "--to", "99:0,0"])
            .status
            .code(),
        Some(2)
    );
    assert_eq!(
        run(&["route", p(&dir), "--from", "0:zero", "--to", "0:0,0"])
            .status
            .code(),
        Some(2)
    );
    assert_eq!(
        run(&["areas", "--sim", "no-such-world", "-o", p(&dir)])
            .status
            .code(),
        Some(2)
    );
}

/// Issue 67: a hybrid.json that breaks its rules exits 2 at once, naming the file and the
/// field; a negative edge length once made `route` search until memory ran out.
#[test]
fn route_refuses_a_hybrid_map_that_breaks_its_rules() {
    let dir = scratch("route-hostile");
    let area = |id: usize| {
        format!(
            r#"{{"id": {id}, "environment": "indoor", "first_from_area": {{"x_m": 0, "y_m": 0, "theta_rad": 0}}}}"#
        )
    };
    let pose = r#"{"x_m": 1, "y_m": 0, "theta_rad": 0}"#;
    let link = |id: usize| {
        format!(
            r#"{{"id": {id}, "areas": [{id}, {}], "poses": [{pose}, {pose}]}}"#,
            id + 1
        )
    };
    let edge = |to: usize, length_m: f64| {
        format!(r#"{{"from": 0, "to": {to}, "area": 1, "length_m": {length_m}}}"#)
    };
    let write = |links: &[String], edges: &[String]| {
        let text = format!(
            r#"{{"areas": [{}, {}, {}], "link_points": [{}], "edges": [{}]}}"#,
            area(0),
            area(1),
            area(2),
            links.join(","),
            edges.join(",")
        );
        std::fs::write(dir.join("hybrid.json"), text).unwrap();
    };
    let route = || run(&["route", p(&dir), "--from", "0:0,0", "--to", "2:0,0"]);
    write(&[link(0), link(1)], &[edge(1, 2.0)]);
    assert!(route().status.success(), "the valid map routes");
    for (links, edges, named) in [
        (
            vec![link(0), link(1)],
            vec![edge(1, -1.0)],
            "edges[0].length_m",
        ),
        (
            vec![link(0), link(1)],
            vec![edge(4, 2.0)],
            "no link point 4",
        ),
        (vec![link(0), link(0)], vec![], "link_points[1].id"),
    ] {
        write(&links, &edges);
        let output = route();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{named}: {stderr}");
        assert!(
            stderr.contains("hybrid.json") && stderr.contains(named),
            "{stderr}"
        );
    }
}

/// Session `index` of the simulated office, added to the store at `site`; areas written to
/// `out`.
fn add_session(site: &std::path::Path, index: &str, out: &std::path::Path) -> serde_json::Value {
    ok_json(&[
        "areas",
        "--sim",
        "office",
        "--seed",
        "1",
        "--session-index",
        index,
        "--duration",
        "300",
        "--store",
        p(site),
        "-o",
        p(out),
        "--json",
    ])
}

#[test]
fn areas_in_the_store_take_a_later_session_placed_by_the_global_search() {
    let dir = scratch("areas-sessions");
    let site = dir.join("site.mapmerge");
    let first = add_session(&site, "0", &dir.join("first"));
    assert_eq!(first["committed_version"].as_i64(), Some(1), "{first}");
    let report = add_session(&site, "1", &dir.join("second"));
    assert_eq!(report["stored_sessions"].as_u64(), Some(1));
    assert_eq!(report["committed_version"].as_i64(), Some(2));
    assert_eq!(report["sessions"].as_u64(), Some(2));
    assert_eq!(report["sessions_placed"].as_u64(), Some(2), "{report}");
    let read = |dir: &std::path::Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join("areas.json")).unwrap()).unwrap()
    };
    let file = read(&dir.join("second"));
    // Some area holds scans of both sessions.
    let both = file["areas"].as_array().unwrap().iter().any(|area| {
        let sessions: Vec<u64> = area["sessions_scans"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s[0].as_u64().unwrap())
            .collect();
        sessions.contains(&0) && sessions.contains(&1)
    });
    assert!(both, "{file}");
    assert!(file["areas"]
        .as_array()
        .unwrap()
        .iter()
        .all(|a| a["placed"] == true));
    // Every passing of both sessions, in its area and in the first area's frame.
    let passings = file["door_passings"].as_array().unwrap();
    for session in [0, 1] {
        assert!(passings.iter().any(|x| x["session"] == session), "{file}");
    }
    assert!(passings
        .iter()
        .all(|x| x["area"].is_u64() && x["placed"] == true && x["x"].is_f64()));
    // The store alone writes the same areas; rolled back, the first session's.
    let again = ok_json(&[
        "areas",
        "--store",
        p(&site),
        "-o",
        p(&dir.join("again")),
        "--json",
    ]);
    assert_eq!(again["committed_version"], serde_json::Value::Null);
    assert_eq!(read(&dir.join("again")), file);
    ok_json(&["store", "rollback", p(&site), "--to", "1", "--json"]);
    ok_json(&[
        "areas",
        "--store",
        p(&site),
        "-o",
        p(&dir.join("back")),
        "--json",
    ]);
    assert_eq!(read(&dir.join("back")), read(&dir.join("first")));
    // Reading a store that does not exist is an error, and creates nothing.
    let missing = dir.join("missing.mapmerge");
    assert_eq!(
        run(&["areas", "--store", p(&missing), "-o", p(&dir.join("x"))])
            .status
            .code(),
        Some(2)
    );
    assert!(!missing.exists());
}
