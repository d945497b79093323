//! Identities of the DyKnow model (seed Table 4.1): transformations (*tid*), computation units
//! (*cid*), targets (*qid*), channels and change sets, one type each, and [`Ids`], the one
//! place that mints fresh names (`cu-N`, `ch-N`, `cs-N`) and reads their numbers back.

use std::borrow::Borrow;
use std::collections::BTreeSet;
use std::fmt;

use serde::{Deserialize, Serialize};

macro_rules! identity {
    ($(#[$doc:meta])* $name:ident) => {
        $(#[$doc])*
        #[derive(Clone, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
        #[serde(transparent)]
        pub struct $name(String);

        /// As the name in quotes (`"cu-9"`), so messages read as before identities were types.
        impl fmt::Debug for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                fmt::Debug::fmt(&self.0, f)
            }
        }

        impl $name {
            /// The identity named `name`.
            pub fn new(name: impl Into<String>) -> Self {
                Self(name.into())
            }

            /// The name.
            pub fn as_str(&self) -> &str {
                &self.0
            }

            /// The name, owned.
            pub fn into_string(self) -> String {
                self.0
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(&self.0)
            }
        }

        impl std::ops::Deref for $name {
            type Target = str;

            fn deref(&self) -> &str {
                &self.0
            }
        }

        impl Borrow<str> for $name {
            fn borrow(&self) -> &str {
                &self.0
            }
        }

        impl AsRef<str> for $name {
            fn as_ref(&self) -> &str {
                &self.0
            }
        }

        impl From<&str> for $name {
            fn from(name: &str) -> Self {
                Self(name.to_owned())
            }
        }

        impl From<String> for $name {
            fn from(name: String) -> Self {
                Self(name)
            }
        }

        impl From<&String> for $name {
            fn from(name: &String) -> Self {
                Self(name.clone())
            }
        }

        impl From<$name> for String {
            fn from(id: $name) -> Self {
                id.0
            }
        }

        impl PartialEq<str> for $name {
            fn eq(&self, other: &str) -> bool {
                self.0 == other
            }
        }

        impl PartialEq<&str> for $name {
            fn eq(&self, other: &&str) -> bool {
                self.0 == *other
            }
        }

        impl PartialEq<String> for $name {
            fn eq(&self, other: &String) -> bool {
                &self.0 == other
            }
        }
    };
}

identity! {
    /// A transformation's identifier, its label (the seed's *tid*, Def. 17).
    Tid
}

identity! {
    /// A computation unit's name (the seed's *cid*, Def. 18). The service mints `cu-N`
    /// ([`Ids::cu`]); a Spawn may give any other name.
    Cid
}

identity! {
    /// A target's identifier, its label (the seed's *qid*, Def. 19).
    Qid
}

identity! {
    /// A channel, by name (a ROS topic in the seed: `/result`, `101`). The service mints
    /// `ch-N` ([`Ids::channel`]).
    Channel
}

identity! {
    /// A change set's identifier, `cs-N`: N counts the change sets of one knowledge base.
    ChangeSetId
}

/// The prefixes of minted names.
const CU_PREFIX: &str = "cu-";
const CHANNEL_PREFIX: &str = "ch-";
const CHANGE_SET_PREFIX: &str = "cs-";

/// The largest N a minted name can have. A client may name a CU `cu-18446744073709551615`;
/// counting on from there would overflow, so larger numbers only reserve their own name.
const MAX_MINTED: u64 = 1 << 53;

/// N of a minted name `<prefix>N`, if `name` is one.
fn number(name: &str, prefix: &str) -> Option<u64> {
    let digits = name.strip_prefix(prefix)?;
    // `cu-007` is not minted (minted numbers have no leading zero), so it reserves nothing.
    if digits.starts_with('0') || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok().filter(|n| *n <= MAX_MINTED)
}

impl Cid {
    /// N, when this is a minted name `cu-N`.
    pub fn minted_number(&self) -> Option<u64> {
        number(&self.0, CU_PREFIX)
    }
}

impl Channel {
    /// N, when this is a minted name `ch-N`.
    pub fn minted_number(&self) -> Option<u64> {
        number(&self.0, CHANNEL_PREFIX)
    }
}

impl ChangeSetId {
    /// Change set number `n`: `cs-n`.
    pub fn numbered(n: u64) -> Self {
        Self(format!("{CHANGE_SET_PREFIX}{n}"))
    }

    /// N of `cs-N`, if this is one.
    pub fn number(&self) -> Option<u64> {
        number(&self.0, CHANGE_SET_PREFIX)
    }
}

/// Fresh names for CUs and channels, never handed out before: `cu-N` and `ch-N` with N above
/// every number seen, skipping names in use (a CU or channel named `cu-5` by a client).
///
/// Invariant: `next_cu` (`next_channel`) is at least every N of a `cu-N` (`ch-N`) handed out
/// or observed, and `taken` holds every other name observed or reserved (a client's `camera`,
/// a channel named `cu-5`). Minted names are only counted, so a service that respawns CUs for
/// months keeps two counters, not every name it ever gave.
#[derive(Debug, Clone, Default)]
pub struct Ids {
    next_cu: u64,
    next_channel: u64,
    taken: BTreeSet<String>,
}

impl Ids {
    /// Identifiers after every CU and channel name the environment uses.
    pub fn after(env: &crate::Environment) -> Self {
        let mut ids = Self::default();
        ids.observe(env);
        ids
    }

    /// Makes sure no CU or channel name the environment uses is handed out.
    pub fn observe(&mut self, env: &crate::Environment) {
        for cu in env.cus.values() {
            self.reserve_cu(&cu.cid);
            for ch in cu.inputs.values().chain(cu.outputs.values()).flatten() {
                self.reserve_channel(ch);
            }
        }
        for t in env.targets.values() {
            self.reserve_channel(&t.channel);
        }
    }

    /// Makes sure no name a change set used is handed out again (the CUs it spawned and the
    /// channels it connected may be gone since).
    pub fn observe_actions(&mut self, actions: &[crate::Action]) {
        for action in actions {
            if let Some(cu) = action.cu() {
                self.reserve_cu(cu);
            }
            if let Some(channel) = action.channel() {
                self.reserve_channel(channel);
            }
        }
    }

    /// Marks a CU name as used.
    pub fn reserve_cu(&mut self, cid: &Cid) {
        if let Some(n) = cid.minted_number() {
            self.next_cu = self.next_cu.max(n);
        } else {
            self.taken.insert(cid.0.clone());
        }
    }

    /// Marks a channel name as used.
    pub fn reserve_channel(&mut self, channel: &Channel) {
        if let Some(n) = channel.minted_number() {
            self.next_channel = self.next_channel.max(n);
        } else {
            self.taken.insert(channel.0.clone());
        }
    }

    /// Whether `name` may not be handed out: observed, reserved or handed out (as a CU or a
    /// channel), or a minted name at or below its counter.
    pub fn is_taken(&self, name: &str) -> bool {
        self.taken.contains(name)
            || number(name, CU_PREFIX).is_some_and(|n| n <= self.next_cu)
            || number(name, CHANNEL_PREFIX).is_some_and(|n| n <= self.next_channel)
    }

    fn fresh(&mut self, prefix: &str, counter: fn(&mut Self) -> &mut u64) -> String {
        loop {
            let n = {
                let c = counter(self);
                *c += 1;
                *c
            };
            // A minted name above the counter can only be taken as a name of the other kind
            // (a CU named `ch-7`), which `taken` holds.
            let id = format!("{prefix}{n}");
            if !self.taken.contains(&id) {
                return id;
            }
        }
    }

    /// The highest minted names handed out or observed, `cu-N` and `ch-N` (none before the
    /// first): reserving them again reserves every minted name below them too.
    pub fn highest_minted(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.next_cu > 0 {
            out.push(format!("{CU_PREFIX}{}", self.next_cu));
        }
        if self.next_channel > 0 {
            out.push(format!("{CHANNEL_PREFIX}{}", self.next_channel));
        }
        out
    }

    /// Reserves a name of either kind: `cu-N` as a CU, `ch-N` as a channel, any other as both.
    pub fn reserve_name(&mut self, name: &str) {
        if number(name, CU_PREFIX).is_some() {
            self.reserve_cu(&Cid::from(name));
        } else {
            self.reserve_channel(&Channel::from(name));
        }
    }

    /// A CU name never used.
    pub fn cu(&mut self) -> Cid {
        Cid(self.fresh(CU_PREFIX, |s| &mut s.next_cu))
    }

    /// A channel name never used.
    pub fn channel(&mut self) -> Channel {
        Channel(self.fresh(CHANNEL_PREFIX, |s| &mut s.next_channel))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minted_names_read_back_their_numbers() {
        let mut ids = Ids::default();
        let cu = ids.cu();
        assert_eq!(cu, "cu-1");
        assert_eq!(cu.minted_number(), Some(1));
        assert_eq!(ids.channel().minted_number(), Some(1));
        assert_eq!(ChangeSetId::numbered(12).number(), Some(12));
        for not_minted in ["cu-", "cu-x", "cu-007", "cu--1", "cu-+1", "ch-1", "camera"] {
            assert_eq!(Cid::from(not_minted).minted_number(), None, "{not_minted}");
        }
        assert_eq!(Channel::from("cu-3").minted_number(), None);
        assert_eq!(ChangeSetId::from("cs-1x").number(), None);
    }

    #[test]
    fn fresh_names_skip_every_name_seen() {
        let mut ids = Ids::default();
        ids.reserve_cu(&Cid::from("cu-4"));
        ids.reserve_cu(&Cid::from("cu-6"));
        ids.reserve_channel(&Channel::from("ch-2"));
        assert_eq!(ids.cu(), "cu-7");
        assert_eq!(ids.channel(), "ch-3");
        // A CU named like a channel (or the reverse) is never handed out as either.
        ids.reserve_cu(&Cid::from("ch-4"));
        assert_eq!(ids.channel(), "ch-5");
        assert!(ids.is_taken("cu-4") && ids.is_taken("ch-4") && !ids.is_taken("cu-8"));
        // Below the counter, a minted name is never handed out: taken.
        assert!(ids.is_taken("cu-5"));
        // Minted names are counted, not kept: a thousand respawns keep the set empty.
        let mut ids = Ids::default();
        for _ in 0..1000 {
            let cu = ids.cu();
            ids.reserve_cu(&cu);
        }
        assert!(ids.taken.is_empty());
        assert_eq!(ids.cu(), "cu-1001");
        // What the highest names reserve, read back into fresh counters.
        ids.channel();
        let mut again = Ids::default();
        for name in ids.highest_minted() {
            again.reserve_name(&name);
        }
        assert_eq!(again.highest_minted(), ["cu-1001", "ch-1"]);
        assert_eq!(again.cu(), "cu-1002");
        again.reserve_name("camera");
        assert!(again.is_taken("camera"));
    }

    #[test]
    fn huge_numbers_reserve_their_name_only() {
        let mut ids = Ids::default();
        let huge = Cid::from("cu-18446744073709551615");
        assert_eq!(huge.minted_number(), None);
        ids.reserve_cu(&huge);
        ids.reserve_cu(&Cid::from("cu-9007199254740992"));
        // 2^53 is the largest number counted on from.
        assert_eq!(ids.cu(), "cu-9007199254740993");
        assert!(ids.is_taken("cu-18446744073709551615"));
    }

    #[test]
    fn identities_print_as_quoted_names() {
        assert_eq!(format!("{:?}", Cid::from("cu-9")), "\"cu-9\"");
        assert_eq!(Cid::from("cu-9").to_string(), "cu-9");
    }

    #[test]
    fn identities_serialise_as_their_names() {
        let cid = Cid::from("cu-3");
        let json = serde_json::to_string(&cid).expect("serialise");
        assert_eq!(json, "\"cu-3\"");
        assert_eq!(serde_json::from_str::<Cid>(&json).expect("parse"), cid);
    }
}
