use super::*;

fn axis(n: u8) -> AxisKey {
    AxisKey {
        bus: "demo".into(),
        node: 1,
        axis: n,
    }
}

const PERIOD: Duration = Duration::from_millis(1000);

fn grant(table: &mut LeaseTable, n: u8, presented: Option<&str>, id: &str, now: Instant) {
    table
        .grant(
            axis(n),
            presented,
            id.into(),
            "plc",
            "velocity",
            PERIOD,
            now,
        )
        .unwrap();
}

#[test]
fn a_held_axis_refuses_others_and_accepts_its_holder() {
    let now = Instant::now();
    let mut table = LeaseTable::new();
    grant(&mut table, 1, None, "aaaa", now);
    assert_eq!(table.check(&axis(1), Some("aaaa"), "plc", now), Ok(()));
    assert_eq!(table.check(&axis(2), None, "plc", now), Ok(()));
    let err = table.check(&axis(1), None, "plc", now).unwrap_err();
    assert_eq!(
        err,
        LeaseError::Conflict {
            axis: axis(1),
            holder: "plc".into(),
            mode: "velocity".into(),
            remaining: PERIOD,
        }
    );
    assert!(err.to_string().contains("expires in 1000 ms"), "{err}");
    let wrong = table.grant(
        axis(1),
        Some("bbbb"),
        "cccc".into(),
        "mes",
        "torque",
        PERIOD,
        now,
    );
    assert!(matches!(wrong, Err(LeaseError::Conflict { .. })));
    assert_eq!(table.get(&axis(1), now).unwrap().holder, "plc");
}

#[test]
fn the_holder_keeps_its_id_when_it_changes_the_set_point() {
    let now = Instant::now();
    let mut table = LeaseTable::new();
    grant(&mut table, 1, None, "aaaa", now);
    let later = now + Duration::from_millis(600);
    let again = table
        .grant(
            axis(1),
            Some("aaaa"),
            "unused".into(),
            "plc",
            "velocity",
            PERIOD,
            later,
        )
        .unwrap();
    assert_eq!(again.id, "aaaa");
    assert_eq!(again.expires, later + PERIOD);
    assert_eq!(table.len(), 1);
}

#[test]
fn renewing_moves_the_expiry_and_an_expired_lease_cannot_be_renewed() {
    let now = Instant::now();
    let mut table = LeaseTable::new();
    grant(&mut table, 1, None, "aaaa", now);
    let t1 = now + Duration::from_millis(900);
    assert_eq!(
        table.renew("aaaa", Some("plc"), None, t1).unwrap().expires,
        t1 + PERIOD
    );
    assert!(table.lapsed(now + Duration::from_millis(1500)).is_empty());
    let t2 = t1 + PERIOD;
    assert_eq!(
        table.renew("aaaa", Some("plc"), None, t2),
        Err(LeaseError::Unknown("aaaa".into()))
    );
    assert_eq!(
        table.renew("zzzz", Some("plc"), None, now),
        Err(LeaseError::Unknown("zzzz".into()))
    );
}

#[test]
fn lapsed_takes_exactly_the_expired_leases_once() {
    let now = Instant::now();
    let mut table = LeaseTable::new();
    grant(&mut table, 1, None, "aaaa", now);
    grant(
        &mut table,
        2,
        None,
        "bbbb",
        now + Duration::from_millis(500),
    );
    assert_eq!(table.next_expiry(), Some(now + PERIOD));
    assert!(
        table
            .lapsed(now + PERIOD - Duration::from_millis(1))
            .is_empty()
    );
    let gone = table.lapsed(now + PERIOD);
    assert_eq!(gone.len(), 1);
    assert_eq!(gone[0].id, "aaaa");
    assert!(table.lapsed(now + PERIOD).is_empty());
    // An expired lease no longer holds its axis, even before lapsed().
    assert_eq!(
        table.check(&axis(2), None, "plc", now + Duration::from_millis(1500)),
        Ok(())
    );
    assert_eq!(table.next_expiry(), Some(now + Duration::from_millis(1500)));
}

#[test]
fn a_lease_bound_to_a_session_lapses_when_the_session_ends() {
    let now = Instant::now();
    let mut table = LeaseTable::new();
    grant(&mut table, 1, None, "aaaa", now);
    grant(&mut table, 2, None, "bbbb", now);
    table.renew("aaaa", None, Some(7), now).unwrap();
    let end = now + Duration::from_millis(100);
    assert_eq!(table.session_ended(7, end), 1);
    assert_eq!(table.session_ended(8, end), 0);
    let gone = table.lapsed(end);
    assert_eq!(
        gone.iter().map(|l| l.id.as_str()).collect::<Vec<_>>(),
        ["aaaa"]
    );
    assert_eq!(table.len(), 1);
}

#[test]
fn releasing_ends_leases_by_axis_by_id_and_all() {
    let now = Instant::now();
    let mut table = LeaseTable::new();
    grant(&mut table, 1, None, "aaaa", now);
    grant(&mut table, 2, None, "bbbb", now);
    assert_eq!(table.release(&axis(1)).unwrap().id, "aaaa");
    assert_eq!(table.release(&axis(1)), None);
    assert_eq!(
        table.release_id("aaaa"),
        Err(LeaseError::Unknown("aaaa".into()))
    );
    grant(&mut table, 3, None, "cccc", now);
    assert_eq!(table.release_id("cccc").unwrap().axis, axis(3));
    assert_eq!(table.release_all().len(), 1);
    assert_eq!(table.len(), 0);
    assert_eq!(table.next_expiry(), None);
}

#[test]
fn a_lease_is_renewed_and_used_by_its_holder_only() {
    let now = Instant::now();
    let mut table = LeaseTable::new();
    grant(&mut table, 1, None, "aaaa", now);
    // The right id, the wrong identity.
    let err = table.renew("aaaa", Some("admin"), None, now).unwrap_err();
    assert_eq!(
        err,
        LeaseError::NotHolder {
            id: "aaaa".into(),
            axis: axis(1),
            holder: "plc".into(),
            by: "admin".into(),
        }
    );
    // The message names the holder, and the id masked.
    let message = err.to_string();
    assert!(message.contains("held by plc, not admin"), "{message}");
    assert!(message.contains("'aaaa…'"), "{message}");
    assert!(matches!(
        table.check(&axis(1), Some("aaaa"), "admin", now),
        Err(LeaseError::NotHolder { .. })
    ));
    let taken = table.grant(
        axis(1),
        Some("aaaa"),
        "cccc".into(),
        "admin",
        "velocity",
        PERIOD,
        now,
    );
    assert!(matches!(taken, Err(LeaseError::NotHolder { .. })));
    // Not renewed by the refusals.
    assert_eq!(table.get(&axis(1), now).unwrap().expires, now + PERIOD);
    // The holder, and the gateway itself, may.
    assert!(table.renew("aaaa", Some("plc"), None, now).is_ok());
    assert!(table.renew("aaaa", None, None, now).is_ok());
}

#[test]
fn a_take_over_ends_the_held_lease_and_its_id() {
    let now = Instant::now();
    let mut table = LeaseTable::new();
    assert_eq!(table.take_over(&axis(1), now), None);
    grant(&mut table, 1, None, "aaaa", now);
    let previous = table.take_over(&axis(1), now).unwrap();
    assert_eq!(
        (previous.id.as_str(), previous.holder.as_str()),
        ("aaaa", "plc")
    );
    assert_eq!(table.len(), 0);
    assert_eq!(
        table.renew("aaaa", Some("plc"), None, now),
        Err(LeaseError::Unknown("aaaa".into()))
    );
    let new = table
        .grant(
            axis(1),
            None,
            "bbbb".into(),
            "admin",
            "velocity",
            PERIOD,
            now,
        )
        .unwrap();
    assert_eq!(new.id, "bbbb");
    assert!(matches!(
        table.check(&axis(1), Some("aaaa"), "plc", now),
        Err(LeaseError::Conflict { .. })
    ));
}

#[test]
fn renewals_are_due_for_audit_once_per_interval() {
    let now = Instant::now();
    let every = Duration::from_secs(60);
    let mut table = LeaseTable::new();
    grant(&mut table, 1, None, "aaaa", now);
    assert!(table.audit_due("aaaa", every, now));
    assert!(!table.audit_due("aaaa", every, now + Duration::from_secs(59)));
    assert!(table.audit_due("aaaa", every, now + every));
    assert!(!table.audit_due("zzzz", every, now));
}

#[test]
fn masked_ids_show_four_characters() {
    assert_eq!(mask("3f2a9c0e5b7d41e8"), "3f2a…");
    assert_eq!(mask("ab"), "ab…");
    let err = LeaseError::Unknown("3f2a9c0e5b7d41e8".into());
    assert!(err.to_string().contains("'3f2a…'"), "{err}");
}
