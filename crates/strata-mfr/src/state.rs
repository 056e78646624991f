//! The per-object selection states (Springer 2008, Fig. 6.5) and the rule of Table 6.1.
//!
//! Every object is in one of three states. A pointer ray that hits an object makes it OVER (the
//! user is about to grab it: the seed's pre-selection, which gives the clients time to hand the
//! object over before it moves); pressing the button selects the OVER object; releasing returns it
//! to OVER; a ray that misses returns an OVER object to INACTIVE:
//!
//! ```text
//!             Intersect                 Select
//!  INACTIVE ─────────────► OVER ─────────────────► SELECTED
//!     ▲   ◄─────────────    │ ▲ ◄───────────────────  │
//!     │     No Intersect    │ │        Release        │
//!     └─────────────────────┘ └─ Intersect            └─ Intersect, No Intersect, Select
//! ```
//!
//! Every other input leaves the state as it is: a button pressed over nothing selects nothing, and
//! a selected object stays selected while it is dragged, wherever the ray points.
//!
//! Table 6.1 adds whether the object is *contained* in the SC buffer the FC composites with. The
//! FC draws an object unless it is INACTIVE and contained:
//!
//! | row | in SC buffer | state | FC draws |
//! | --- | --- | --- | --- |
//! | 1 | no | INACTIVE | yes (released, not yet back in the SC buffer) |
//! | 2 | no | OVER | yes |
//! | 3 | no | SELECTED | yes |
//! | 4 | yes | INACTIVE | no (an ordinary static object) |
//! | 5 | yes | OVER | yes |
//! | 6 | yes | SELECTED | yes |

use serde::{Deserialize, Serialize};

/// An object's selection state (Fig. 6.5).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ObjectState {
    /// Not under the pointer: the slow client may render it.
    #[default]
    Inactive,
    /// Under the pointer (pre-selected): handed to the fast client.
    Over,
    /// Grabbed: the fast client renders it where the user moves it.
    Selected,
}

/// What happens to one object.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Input {
    /// The pointer ray hits the object (its bounding box).
    Intersect,
    /// The pointer ray misses it.
    NoIntersect,
    /// The button is pressed while the object is under the pointer.
    Select,
    /// The button is released while the object is selected.
    Release,
}

impl ObjectState {
    /// The state after `input` (Fig. 6.5; inputs without an edge leave the state unchanged).
    pub fn next(self, input: Input) -> ObjectState {
        use {Input::*, ObjectState::*};
        match (self, input) {
            (Inactive, Intersect) => Over,
            (Over, NoIntersect) => Inactive,
            (Over, Select) => Selected,
            (Selected, Release) => Over,
            (state, _) => state,
        }
    }
}

/// Table 6.1: whether the fast client draws an object in `state` that the slow client's buffer
/// does (`contained`) or does not hold.
pub fn fc_renders(state: ObjectState, contained: bool) -> bool {
    !(state == ObjectState::Inactive && contained)
}

/// The row of Table 6.1 (1–6) an object is in, for logs.
pub fn table_6_1_row(state: ObjectState, contained: bool) -> u8 {
    let base = if contained { 4 } else { 1 };
    base + match state {
        ObjectState::Inactive => 0,
        ObjectState::Over => 1,
        ObjectState::Selected => 2,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_6_1_row_by_row() {
        use ObjectState::*;
        let rows = [
            (false, Inactive, 1, true),
            (false, Over, 2, true),
            (false, Selected, 3, true),
            (true, Inactive, 4, false),
            (true, Over, 5, true),
            (true, Selected, 6, true),
        ];
        for (contained, state, row, draws) in rows {
            assert_eq!(table_6_1_row(state, contained), row);
            assert_eq!(fc_renders(state, contained), draws, "row {row}");
        }
    }
}
