//! Channel keys declared once per Zenoh session: a workaround for how Zenoh 1.10 numbers
//! key-expression declarations.
//!
//! A session numbers the key expressions its publishers, subscribers and queryables declare
//! with a `u16` that wraps without regard to the numbers still in use
//! (`zenoh::api::session::SessionState::expr_id_counter`: "@TODO: manage rollover and
//! uniqueness"). After 65,535 declarations a new one takes the number of a live one, and
//! undeclaring it later removes the live one's mapping on both ends of the link: the router
//! then drops that publisher's samples ("Received Data for unknown expr_id"). A CU declares its
//! channels' keys when its ports are bound and undeclares them when it stops, so every restart
//! took a number; after ~65,500 CU crashes on one executor (11 minutes of a 100 crashes/s
//! storm) the CUs that had never crashed stopped delivering (docs/reliability.md, guarantee 3).
//!
//! [`pinned_key`] keeps the last [`KEPT`] keys declared through it per session: a CU restarted
//! on channels used recently takes no new number. A session still takes one per distinct
//! channel it binds (and per channel bound again after [`KEPT`] others), so the limit moves
//! from 65,535 restarts to 65,535 distinct channels.

use std::collections::HashMap;
use std::sync::{LazyLock, Mutex, PoisonError};

use zenoh::Wait;
use zenoh::key_expr::KeyExpr;

/// How many keys each session keeps declared once nothing uses them.
pub const KEPT: usize = 1024;

#[derive(Default)]
struct Kept {
    keys: HashMap<String, (KeyExpr<'static>, u64)>,
    clock: u64,
}

/// Per session (its Zenoh id), the keys declared through [`pinned_key`] and when each was
/// last asked for. A closed session's entry stays (at most [`KEPT`] keys; a process opens few
/// sessions).
static PINS: LazyLock<Mutex<HashMap<String, Kept>>> = LazyLock::new(Mutex::default);

/// `key` declared on `session`, reusing the declaration made for it before if it is among the
/// last [`KEPT`] keys asked for; a publisher or subscriber declared on the result shares that
/// declaration's number.
pub fn pinned_key(
    session: &zenoh::Session,
    key: KeyExpr<'static>,
) -> Result<KeyExpr<'static>, zenoh::Error> {
    let mut pins = PINS.lock().unwrap_or_else(PoisonError::into_inner);
    let kept = pins.entry(session.zid().to_string()).or_default();
    kept.clock += 1;
    let clock = kept.clock;
    if let Some((declared, last)) = kept.keys.get_mut(key.as_str()) {
        *last = clock;
        return Ok(declared.clone());
    }
    let declared = session.declare_keyexpr(key).wait()?;
    if kept.keys.len() >= KEPT
        && let Some(oldest) = kept
            .keys
            .iter()
            .min_by_key(|(_, (_, last))| *last)
            .map(|(k, _)| k.clone())
    {
        // Undeclared once no publisher or subscriber uses it either.
        kept.keys.remove(&oldest);
    }
    kept.keys
        .insert(declared.as_str().to_owned(), (declared.clone(), clock));
    Ok(declared)
}
