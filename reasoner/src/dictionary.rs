//! Integer encoding of RDF terms: the reasoner works on `[Id; 3]` facts.

use oxrdf::Term;
use rustc_hash::FxHashMap;

/// The identifier of a term in a [`Dictionary`].
pub type Id = u32;

/// A fact: subject, predicate, object, as term identifiers.
pub type Fact = [Id; 3];

/// A two-way map between terms and identifiers. Identifiers are never reused, so a fact keeps
/// its meaning for the life of the reasoner.
#[derive(Debug, Default, Clone)]
pub struct Dictionary {
    terms: Vec<Term>,
    literal: Vec<bool>,
    ids: FxHashMap<Term, Id>,
}

impl Dictionary {
    /// The identifier of `term`, allocated if new.
    pub fn encode(&mut self, term: impl Into<Term>) -> Id {
        let term = term.into();
        if let Some(id) = self.ids.get(&term) {
            return *id;
        }
        let id = Id::try_from(self.terms.len()).unwrap_or(Id::MAX);
        self.literal.push(matches!(term, Term::Literal(_)));
        self.terms.push(term.clone());
        self.ids.insert(term, id);
        id
    }

    /// The identifier of `term`, if it was ever encoded.
    pub fn get(&self, term: &Term) -> Option<Id> {
        self.ids.get(term).copied()
    }

    /// The term of `id`.
    ///
    /// # Panics
    /// If `id` was not allocated by this dictionary.
    pub fn decode(&self, id: Id) -> &Term {
        &self.terms[id as usize]
    }

    /// Whether `id` is a literal (literals cannot be subjects).
    pub fn is_literal(&self, id: Id) -> bool {
        self.literal.get(id as usize).copied().unwrap_or(false)
    }
}
