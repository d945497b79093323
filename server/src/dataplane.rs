//! The service's data plane (`executors.md`): its Zenoh router, the embedded executor `local`,
//! and the task that hands what the executors report to the life-cycle (crashes as
//! perturbations, measured CPU costs as observations, executors coming and going as
//! registrations and deregistrations).

use std::sync::Arc;
use std::time::Duration;

use dyknow_cu::zenoh::{self, Wait};
use dyknow_lifecycle::{FleetEvent, LifecycleError, Manager, Observation, Perturbation};
use tokio::sync::mpsc::UnboundedReceiver;
use tokio::time::Instant;

/// Zenoh's default link lease, in milliseconds.
pub const DEFAULT_LEASE_MS: u64 = 10_000;

/// A Zenoh router configuration: listening on `listen`, connecting to `connect`, scouting off
/// (explicit endpoints only), links declared gone after `lease_ms` of silence.
pub fn router_config(
    listen: &[String],
    connect: &[String],
    lease_ms: u64,
) -> Result<zenoh::Config, String> {
    if !(100..=3_600_000).contains(&lease_ms) {
        return Err(format!(
            "the Zenoh lease must be between 100 ms and one hour, not {lease_ms} ms"
        ));
    }
    let json = |v: &[String]| serde_json::to_string(v).unwrap_or_default();
    let mut config = zenoh::Config::default();
    let set = |config: &mut zenoh::Config, key: &str, value: &str| {
        config
            .insert_json5(key, value)
            .map_err(|e| format!("zenoh configuration {key}: {e}"))
    };
    set(&mut config, "mode", "\"router\"")?;
    set(&mut config, "listen/endpoints", &json(listen))?;
    set(&mut config, "connect/endpoints", &json(connect))?;
    set(&mut config, "scouting/multicast/enabled", "false")?;
    set(&mut config, "scouting/gossip/enabled", "false")?;
    set(
        &mut config,
        "transport/link/tx/lease",
        &lease_ms.to_string(),
    )?;
    // A lost link to a configured endpoint (the manager restarting) is retried every 250 ms
    // at first and at least once a second, not with Zenoh's default back-off up to 4 s: an
    // executor is back well within the manager's start-up grace.
    set(
        &mut config,
        "connect/retry",
        r#"{"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}"#,
    )?;
    Ok(config)
}

/// A Zenoh client configuration connecting to `connect` (for `dyknow listen`).
pub fn client_config(connect: &[String]) -> Result<zenoh::Config, String> {
    dyknow_cu::client_config(connect).map_err(|e| e.to_string())
}

/// Opens a session.
pub fn open(config: zenoh::Config) -> Result<zenoh::Session, String> {
    zenoh::open(config)
        .wait()
        .map_err(|e| format!("cannot open the Zenoh session: {e}"))
}

/// Hands the fleet's events to the manager until the fleet is gone. Measured costs are
/// batched: one store write per `flush` interval. Upkeep is converted to CPU ms per time
/// unit. An executor that appears is reconciled with the model; `grace` after the start (or
/// as soon as every CU of the model runs somewhere) the start-up reconciliation respawns what
/// runs nowhere and lets reviews run.
pub async fn forward(
    mut events: UnboundedReceiver<FleetEvent>,
    manager: Arc<Manager>,
    flush: Duration,
    grace: Duration,
) {
    let time_unit_ms = manager.settings().time_unit.as_secs_f64() * 1e3;
    let mut pending: Vec<Observation> = Vec::new();
    let mut tick = tokio::time::interval(flush);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let start_up = tokio::time::sleep_until(Instant::now() + grace);
    tokio::pin!(start_up);
    let mut starting = manager.starting();
    if starting && all_placed(&manager).await {
        starting = false;
        start_up_reconcile(&manager).await;
    }
    loop {
        tokio::select! {
            () = &mut start_up, if starting => {
                starting = false;
                start_up_reconcile(&manager).await;
            }
            event = events.recv() => {
                let Some(event) = event else { break };
                match event {
                    FleetEvent::Appeared { executor, cus } => {
                        let m = manager.clone();
                        run(move || m.reconcile(Some(&executor), cus, false).map(|_| ())).await;
                        if starting && all_placed(&manager).await {
                            starting = false;
                            start_up_reconcile(&manager).await;
                        }
                    }
                    FleetEvent::ExecutorsChanged => {
                        let m = manager.clone();
                        run(move || m.executors_changed()).await;
                    }
                    FleetEvent::Crashed { cu, reason } => {
                        tracing::warn!("{cu} crashed: {reason}");
                        let m = manager.clone();
                        let name = cu.clone();
                        match tokio::task::spawn_blocking(move || {
                            m.report(Perturbation::CuCrashed { cu: name })
                        })
                        .await
                        {
                            Ok(Ok(())) | Ok(Err(LifecycleError::UnknownCu(_))) => {}
                            Ok(Err(e)) => tracing::error!("cannot record the crash of {cu}: {e}"),
                            Err(e) => tracing::error!("crash report panicked: {e}"),
                        }
                    }
                    FleetEvent::Labour { transformation, cpu_ms } => {
                        pending.push(Observation::Labour { transformation, value: cpu_ms });
                    }
                    FleetEvent::Upkeep { cu, cpu_ms, over_ms } => {
                        if over_ms > 0.0 {
                            pending.push(Observation::Upkeep {
                                cu,
                                value: cpu_ms * time_unit_ms / over_ms,
                            });
                        }
                    }
                }
            }
            _ = tick.tick() => {
                if !pending.is_empty() {
                    let batch = std::mem::take(&mut pending);
                    let m = manager.clone();
                    run(move || m.observe_all(batch).map(|_| ())).await;
                }
            }
        }
    }
}

/// Whether every CU of the model runs on some executor.
async fn all_placed(manager: &Arc<Manager>) -> bool {
    let m = manager.clone();
    matches!(
        tokio::task::spawn_blocking(move || m.all_placed()).await,
        Ok(Ok(true))
    )
}

/// The start-up pass of reconciliation: respawns what runs nowhere, then reviews may run.
async fn start_up_reconcile(manager: &Arc<Manager>) {
    let m = manager.clone();
    run(move || m.reconcile(None, Vec::new(), true).map(|_| ())).await;
}

async fn run(f: impl FnOnce() -> Result<(), LifecycleError> + Send + 'static) {
    match tokio::task::spawn_blocking(f).await {
        Ok(Ok(())) => {}
        Ok(Err(e)) => tracing::error!("data plane: {e}"),
        Err(e) => tracing::error!("data plane: {e}"),
    }
}
