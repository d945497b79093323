//! The service's data plane (`executors.md`): its Zenoh router, the embedded executor `local`,
//! and the task that hands what the executors report to the life-cycle (crashes as
//! perturbations, measured CPU costs as observations, executors coming and going as
//! registrations and deregistrations).

use std::sync::Arc;
use std::time::Duration;

use dyknow_cu::zenoh::{self, Wait};
use dyknow_lifecycle::{FleetEvent, LifecycleError, Manager, Observation, Perturbation};
use tokio::sync::mpsc::UnboundedReceiver;

/// A Zenoh router configuration: listening on `listen`, connecting to `connect`, scouting off
/// (explicit endpoints only).
pub fn router_config(listen: &[String], connect: &[String]) -> Result<zenoh::Config, String> {
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
/// unit.
pub async fn forward(
    mut events: UnboundedReceiver<FleetEvent>,
    manager: Arc<Manager>,
    flush: Duration,
) {
    let time_unit_ms = manager.settings().time_unit.as_secs_f64() * 1e3;
    let mut pending: Vec<Observation> = Vec::new();
    let mut tick = tokio::time::interval(flush);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            event = events.recv() => {
                let Some(event) = event else { break };
                match event {
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

async fn run(f: impl FnOnce() -> Result<(), LifecycleError> + Send + 'static) {
    match tokio::task::spawn_blocking(f).await {
        Ok(Ok(())) => {}
        Ok(Err(e)) => tracing::error!("data plane: {e}"),
        Err(e) => tracing::error!("data plane: {e}"),
    }
}
