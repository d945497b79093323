//! The source and sink of a chain of dora relays: sends a small JSON sample
//! (a DyKnow sample, `{"t":<unix ms>,"value":<seq>}`) on output `out` and times, with one monotonic clock, its
//! arrival on input `in` (from the last relay). 50 samples warm up, then `MESSAGES` are timed,
//! back to back (`RATE=0`: the next when the last arrived) or one every 1/`RATE` s. Prints (and
//! appends to `RESULT_FILE`, if set) one line: `n=<HOPS> mean=<µs> p50=<µs> p99=<µs>`.

use std::io::Write;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use dora_node_api::{DoraNode, Event, EventStream, MetadataParameters, dora_core::config::DataId};
use eyre::{ContextCompat, bail};

const WARMUP: u64 = 50;
/// Sequence numbers of the samples that probe whether the chain carries data yet.
const PROBE: u64 = 1 << 40;

fn env<T: std::str::FromStr>(name: &str, default: T) -> eyre::Result<T> {
    match std::env::var(name) {
        Ok(v) => v.parse().ok().with_context(|| format!("bad {name}={v}")),
        Err(_) => Ok(default),
    }
}

fn payload(seq: u64) -> Vec<u8> {
    let t = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default();
    format!(r#"{{"t":{},"value":{seq}}}"#, t.as_millis()).into_bytes()
}

/// The `value` of a payload made by [`payload`].
fn seq_of(payload: &[u8]) -> Option<u64> {
    let s = std::str::from_utf8(payload).ok()?;
    let v = s.split(r#""value":"#).nth(1)?;
    v.trim_end_matches('}').parse().ok()
}

/// Waits up to `timeout` for the sample `seq` on `in`; the arrival time if it came.
fn arrival(events: &mut EventStream, seq: u64, timeout: Duration) -> eyre::Result<Option<Instant>> {
    let deadline = Instant::now() + timeout;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match events.recv_timeout(left) {
            Some(Event::Input { data, .. }) => {
                let at = Instant::now();
                let bytes: &[u8] = (&data).try_into()?;
                if seq_of(bytes) == Some(seq) {
                    return Ok(Some(at));
                }
            }
            Some(Event::Stop(_)) => bail!("stopped"),
            Some(_) => {}
            None if Instant::now() >= deadline => return Ok(None),
            None => bail!("the event stream closed"),
        }
    }
}

fn main() -> eyre::Result<()> {
    dyknow_dora_chain::init_log();
    let messages: usize = env("MESSAGES", 1000)?;
    let rate: f64 = env("RATE", 0.0)?;
    let hops: String = env("HOPS", "?".to_owned())?;
    if messages == 0 {
        bail!("MESSAGES must be at least 1");
    }
    let (mut node, mut events) = DoraNode::init_from_env()?;
    let out = DataId::from("out".to_owned());
    let send = |node: &mut DoraNode, seq: u64| {
        let p = payload(seq);
        node.send_output_bytes(out.clone(), MetadataParameters::default(), p.len(), &p)
    };
    // Until the chain carries samples.
    let ready = Instant::now() + Duration::from_secs(60);
    for probe in PROBE.. {
        send(&mut node, probe)?;
        if arrival(&mut events, probe, Duration::from_millis(100))?.is_some() {
            break;
        }
        if Instant::now() > ready {
            bail!("the chain carries nothing");
        }
    }
    let period = (rate > 0.0).then(|| Duration::from_secs_f64(1.0 / rate));
    let mut times = Vec::with_capacity(messages);
    for seq in 0..WARMUP + messages as u64 {
        let started = Instant::now();
        send(&mut node, seq)?;
        let Some(at) = arrival(&mut events, seq, Duration::from_secs(10))? else {
            bail!("sample {seq} lost");
        };
        if seq >= WARMUP {
            times.push(at - started);
            if let Some(p) = period {
                std::thread::sleep((started + p).saturating_duration_since(Instant::now()));
            }
        }
    }
    times.sort();
    let us = |d: Duration| d.as_secs_f64() * 1e6;
    let pct = |p: f64| us(times[((times.len() as f64 * p) as usize).min(times.len() - 1)]);
    let mean = times.iter().map(|d| us(*d)).sum::<f64>() / times.len() as f64;
    let line = format!(
        "n={hops} mean={mean:.1} p50={:.1} p99={:.1}",
        pct(0.5),
        pct(0.99)
    );
    println!("{line}");
    if let Ok(path) = std::env::var("RESULT_FILE") {
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)?;
        writeln!(f, "{line}")?;
    }
    Ok(())
}
