//! A panic in a CU's callback is a crash the executor reports; it does not go through the
//! process's panic hook (which, with `RUST_BACKTRACE` set, resolves a backtrace for hundreds of
//! milliseconds and so delays the crash report). Panics elsewhere still do.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use dyknow_cu::zenoh::{self, Wait};
use dyknow_cu::{CuError, Namespace, NodeHandle, Sample, Timers, Transformation, Unit, UnitSpec};

struct Panics;

impl Transformation for Panics {
    fn on_sample(&mut self, _: &mut NodeHandle<'_>, _: &str, _: Sample) -> Result<(), CuError> {
        panic!("on purpose");
    }
}

#[test]
fn a_panicking_callback_crashes_its_cu_without_the_process_panic_hook() {
    // Whatever hook the process had: here one that counts.
    let hooked = Arc::new(AtomicUsize::new(0));
    let count = hooked.clone();
    std::panic::set_hook(Box::new(move |_| {
        count.fetch_add(1, Ordering::SeqCst);
    }));
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", "\"peer\"").unwrap();
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    config.insert_json5("listen/endpoints", "[]").unwrap();
    let session = zenoh::open(config).wait().unwrap();
    let (crashed_tx, crashed) = mpsc::channel();
    let timers = Timers::start();
    let started = Unit::start(
        &session,
        &Namespace::default(),
        UnitSpec {
            name: "p".into(),
            transformation: "panics".into(),
            inputs: vec!["in".into()],
            outputs: vec![],
            params: Default::default(),
        },
        Box::new(Panics),
        &timers,
        Box::new(move |reason| {
            let _ = crashed_tx.send(reason.to_owned());
        }),
    )
    .unwrap();
    started.unit.bind_in("in", Some("c")).unwrap();
    let key = Namespace::default().channel("c").unwrap();
    session
        .put(&key, Sample::new(1, 1).to_bytes())
        .wait()
        .unwrap();
    let reason = crashed
        .recv_timeout(Duration::from_secs(10))
        .expect("the CU to crash");
    assert!(reason.contains("on purpose"), "{reason}");
    assert_eq!(
        hooked.load(Ordering::SeqCst),
        0,
        "a CU panic reached the hook"
    );
    // A panic outside any callback still reaches the process's hook.
    let _ = std::panic::catch_unwind(|| panic!("elsewhere"));
    assert_eq!(hooked.load(Ordering::SeqCst), 1);
    started.unit.release();
}
