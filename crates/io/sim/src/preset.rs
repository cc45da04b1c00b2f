//! World parameters, the named presets, and [`generate_world`], which dispatches to the
//! office, warehouse or symmetric-hall generator.

use std::fmt;

use serde::{Deserialize, Serialize};

use crate::hall::{generate_symmetric_hall, SymmetricHallParams};
use crate::office::{generate_office, OfficeParams};
use crate::warehouse::{generate_warehouse, WarehouseParams};
use crate::{SimError, World};

/// Which generator builds the world, with its parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum LayoutParams {
    /// An office floor: rooms along corridors.
    Office(OfficeParams),
    /// A warehouse hall with racking.
    Warehouse(WarehouseParams),
    /// A point-symmetric hall with rooms between two office wings.
    SymmetricHall(SymmetricHallParams),
}

/// Everything [`generate_world`] needs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorldParams {
    /// Name given to the world (default: `office`).
    pub name: String,
    /// The generator and its parameters (default: the `office` preset's).
    pub layout: LayoutParams,
}

impl Default for WorldParams {
    fn default() -> Self {
        WorldPreset::Office.params()
    }
}

/// The named worlds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WorldPreset {
    /// `office`: a 30 × 20 m floor, two corridors joined by two connectors (one loop), rooms
    /// of varied size and furniture.
    Office,
    /// `office-aliased`: a 40 × 20 m floor with a ring corridor, a corridor section (rooms on
    /// both sides, doors and furniture) repeated twice, and three identical rooms side by side.
    OfficeAliased,
    /// `corridor-loop`: a 36 × 22 m floor whose two corridors and two end connectors make one
    /// ring, rooms outside and inside it; good for loop closures.
    CorridorLoop,
    /// `warehouse`: a 40 × 30 m hall with identical rows of racking, a cross aisle, a loading
    /// area with pallets and two offices; highly repetitive.
    Warehouse,
    /// `symmetric-hall`: a 40 × 20 m floor: a 14 m wide hall with a row of rooms on either
    /// side, between two different office wings. The hall block (walls, doors, rooms,
    /// furniture, pillars) is point-symmetric about the hall's centre, so places on opposite
    /// sides of it look alike when seen turned by 180°; the wings tell them apart.
    SymmetricHall,
}

impl WorldPreset {
    /// Every preset, in the order of [`WorldPreset::names`].
    pub const ALL: [WorldPreset; 5] = [
        WorldPreset::Office,
        WorldPreset::OfficeAliased,
        WorldPreset::CorridorLoop,
        WorldPreset::Warehouse,
        WorldPreset::SymmetricHall,
    ];

    /// The names of every preset.
    pub fn names() -> Vec<&'static str> {
        Self::ALL.iter().map(|p| p.name()).collect()
    }

    /// The preset called `name`; the error lists the valid names.
    pub fn from_name(name: &str) -> Result<Self, SimError> {
        Self::ALL
            .iter()
            .copied()
            .find(|p| p.name() == name)
            .ok_or_else(|| SimError::UnknownPreset {
                name: name.to_owned(),
                valid: Self::names().join(", "),
            })
    }

    /// The preset's name.
    pub fn name(self) -> &'static str {
        match self {
            WorldPreset::Office => "office",
            WorldPreset::OfficeAliased => "office-aliased",
            WorldPreset::CorridorLoop => "corridor-loop",
            WorldPreset::Warehouse => "warehouse",
            WorldPreset::SymmetricHall => "symmetric-hall",
        }
    }

    /// The preset's world parameters.
    pub fn params(self) -> WorldParams {
        let layout = match self {
            WorldPreset::Office => LayoutParams::Office(OfficeParams::default()),
            WorldPreset::OfficeAliased => LayoutParams::Office(OfficeParams {
                width_m: 40.0,
                height_m: 20.0,
                connector_positions: vec![0.0, 1.0],
                aliased_room_copies: 3,
                aliased_room_width_m: 4.5,
                repeated_section_copies: 2,
                repeated_section_width_m: 9.0,
                ..OfficeParams::default()
            }),
            WorldPreset::CorridorLoop => LayoutParams::Office(OfficeParams {
                width_m: 36.0,
                height_m: 22.0,
                connector_positions: vec![0.0, 1.0],
                ..OfficeParams::default()
            }),
            WorldPreset::Warehouse => LayoutParams::Warehouse(WarehouseParams::default()),
            WorldPreset::SymmetricHall => {
                LayoutParams::SymmetricHall(SymmetricHallParams::default())
            }
        };
        WorldParams {
            name: self.name().to_owned(),
            layout,
        }
    }
}

impl fmt::Display for WorldPreset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for WorldPreset {
    type Err = SimError;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        Self::from_name(name)
    }
}

/// Generates a world from `params`; the same parameters and seed give the same world, bit for
/// bit. Every destination room is reachable by a robot of the default clearance (furniture
/// that would block one is left out).
pub fn generate_world(params: &WorldParams, seed: u64) -> Result<World, SimError> {
    match &params.layout {
        LayoutParams::Office(office) => generate_office(&params.name, office, seed),
        LayoutParams::Warehouse(warehouse) => generate_warehouse(&params.name, warehouse, seed),
        LayoutParams::SymmetricHall(hall) => generate_symmetric_hall(&params.name, hall, seed),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_names_list_the_valid_ones() {
        for preset in WorldPreset::ALL {
            assert_eq!(WorldPreset::from_name(preset.name()).unwrap(), preset);
        }
        let err = WorldPreset::from_name("castle").unwrap_err().to_string();
        assert!(
            err.contains("castle")
                && err.contains("office-aliased")
                && err.contains("warehouse")
                && err.contains("symmetric-hall"),
            "{err}"
        );
    }
}
