//! Register map of the OPT9221 ToF controller on the OPT8241-CDK.
//!
//! Registers are 24 bits wide; a field is a bit range `[msb:lsb]` of one
//! register and is written read-modify-write. An address is `slave << 8 |
//! register`: slave 0x58 is the timing generator (DML bank 0), slave 0x5C the
//! depth engine (DML bank 3) — TI Voxel SDK `TI3DToF/ToFTintinCamera.cpp`
//! (`_init`, bank-to-slave mapping) and `TI3DToF/OPT9221.dml` (field ranges).
//! Every field below cites its DML name; `docs/hardware.md` has the table.

/// I2C slave of the timing generator (DML bank 0).
pub const SLAVE_TIMING_GENERATOR: u8 = 0x58;
/// I2C slave of the depth engine (DML bank 3).
pub const SLAVE_DEPTH_ENGINE: u8 = 0x5C;
/// Width of every OPT9221 register.
pub const REGISTER_BITS: u32 = 24;
/// Mask of a whole register.
pub const REGISTER_MASK: u32 = (1 << REGISTER_BITS) - 1;

/// A value that does not fit its field.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{field} = {value} does not fit bits [{msb}:{lsb}] (max {max})")]
pub struct FieldRangeError {
    pub field: &'static str,
    pub value: u32,
    pub msb: u8,
    pub lsb: u8,
    pub max: u32,
}

/// One bit range of a 24-bit register.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Field {
    /// DML name.
    pub name: &'static str,
    /// `slave << 8 | register`.
    pub address: u16,
    pub msb: u8,
    pub lsb: u8,
    /// Read-only status fields are never written.
    pub read_only: bool,
}

impl Field {
    const fn rw(name: &'static str, address: u16, msb: u8, lsb: u8) -> Self {
        Self {
            name,
            address,
            msb,
            lsb,
            read_only: false,
        }
    }

    const fn ro(name: &'static str, address: u16, msb: u8, lsb: u8) -> Self {
        Self {
            name,
            address,
            msb,
            lsb,
            read_only: true,
        }
    }

    /// I2C slave (wValue of the vendor request).
    pub const fn slave(&self) -> u8 {
        (self.address >> 8) as u8
    }

    /// Register inside the slave (wIndex of the vendor request).
    pub const fn register(&self) -> u8 {
        self.address as u8
    }

    pub const fn width_bits(&self) -> u32 {
        (self.msb - self.lsb) as u32 + 1
    }

    /// Largest value the field holds.
    pub const fn max(&self) -> u32 {
        (1u32 << self.width_bits()) - 1
    }

    /// The field's bits in place inside the register.
    pub const fn mask(&self) -> u32 {
        self.max() << self.lsb
    }

    /// The field's value out of a whole register value.
    pub const fn extract(&self, register_value: u32) -> u32 {
        (register_value & self.mask()) >> self.lsb
    }

    /// Read-modify-write: `register_value` with this field replaced by `value`,
    /// every other bit kept.
    pub fn insert(&self, register_value: u32, value: u32) -> Result<u32, FieldRangeError> {
        if value > self.max() {
            return Err(FieldRangeError {
                field: self.name,
                value,
                msb: self.msb,
                lsb: self.lsb,
                max: self.max(),
            });
        }
        Ok(((register_value & !self.mask()) | (value << self.lsb)) & REGISTER_MASK)
    }
}

/// The fields sdid touches or reports (OPT9221.dml; address = 0x58xx for
/// bank 0, 0x5Cxx for bank 3).
pub mod field {
    use super::Field;

    // --- timing generator (slave 0x58, DML bank 0) ---
    /// 1 stops the TFC and streaming.
    pub const TG_DIS: Field = Field::rw("tg_dis", 0x5880, 0, 0);
    /// System clocks per quad: frame time / (sub frames * quads).
    pub const PIX_CNT_MAX: Field = Field::rw("pix_cnt_max", 0x5882, 21, 0);
    /// Quads per sub frame: only 4 or 6 are valid.
    pub const QUAD_CNT_MAX: Field = Field::rw("quad_cnt_max", 0x5883, 3, 0);
    /// Sub frames per frame: 1, 2, 4 or 8.
    pub const SUB_FRAME_CNT_MAX: Field = Field::rw("sub_frame_cnt_max", 0x5883, 7, 4);
    /// Toggle 1 then 0 after changing the PLL fields.
    pub const MOD_PLL_UPDATE: Field = Field::rw("mod_pll_update", 0x5802, 2, 2);
    pub const MOD_M_FRAC1: Field = Field::rw("mod_m_frac1", 0x580C, 15, 0);
    pub const MOD_M1: Field = Field::rw("mod_m1", 0x580C, 21, 16);
    pub const MOD_N1: Field = Field::rw("mod_n1", 0x580F, 1, 0);
    pub const MOD_PS1: Field = Field::rw("mod_ps1", 0x580F, 6, 4);
    /// Spread-spectrum clocking: sdid turns it off.
    pub const SSCG_EN: Field = Field::rw("sscg_en", 0x580E, 3, 3);
    /// Masked by the CDK firmware (laser safety): never written by sdid.
    pub const ILLUM_DC_CORR: Field = Field::rw("illum_dc_corr", 0x580E, 16, 13);
    pub const ILLUM_DC_CORR_DIR: Field = Field::rw("illum_dc_corr_dir", 0x580E, 17, 17);
    /// Inactive level of ILLUM_P / ILLUM_N.
    pub const ILLUM_P_DIS_POL: Field = Field::rw("illum_p_dis_pol", 0x580B, 4, 4);
    pub const ILLUM_N_DIS_POL: Field = Field::rw("illum_n_dis_pol", 0x580B, 3, 3);
    /// Holds modulation and demodulation static.
    pub const MODULATION_HOLD: Field = Field::rw("modulation_hold", 0x580F, 18, 18);
    pub const DEMOD_STATIC_POL: Field = Field::rw("demod_static_pol", 0x580F, 19, 19);
    pub const ILLUM_STATIC_POL: Field = Field::rw("illum_static_pol", 0x580F, 20, 20);
    /// Region of interest (columns in units of 16).
    pub const ROW_START: Field = Field::rw("row_start", 0x581F, 7, 0);
    pub const ROW_END: Field = Field::rw("row_end", 0x581F, 23, 16);
    pub const COL_START: Field = Field::rw("col_start", 0x5820, 7, 3);
    pub const COL_END: Field = Field::rw("col_end", 0x5821, 7, 3);

    // --- depth engine (slave 0x5C, DML bank 3) ---
    /// 0 depth, 1 raw I/Q, 15 raw quads.
    pub const OUTPUT_MODE: Field = Field::rw("output_mode", 0x5C25, 11, 8);
    pub const OP_DATA_ARRANGE_MODE: Field = Field::rw("op_data_arrange_mode", 0x5C25, 19, 18);
    pub const PIXEL_DATA_SIZE: Field = Field::rw("pixel_data_size", 0x5C27, 14, 11);
    pub const BINNING_EN: Field = Field::rw("binning_en", 0x5C2F, 12, 12);
    pub const BIN_ROW_COUNT: Field = Field::rw("bin_row_count", 0x5C2F, 23, 14);
    pub const BIN_COL_COUNT: Field = Field::rw("bin_col_count", 0x5C30, 23, 14);
    /// 0: 24 MHz output clock (1: 12, 2: 6, 3: 3).
    pub const OP_CLK_FREQ: Field = Field::rw("op_clk_freq", 0x5C39, 2, 1);
    /// Replaces the first byte of each frame by the frame number.
    pub const DEBUG_FRAME_NUMBER_EN: Field = Field::rw("debug_frame_number_en", 0x5C39, 12, 12);
    pub const BLK_HEADER_EN: Field = Field::rw("blk_header_en", 0x5C3C, 2, 2);
    pub const BLK_SIZE: Field = Field::rw("blk_size", 0x5C3C, 23, 4);
    /// Second modulation PLL (dealiasing's other frequency; SDK `VCO_FREQ2`).
    pub const MOD_M2: Field = Field::rw("mod_m2", 0x580D, 21, 16);
    pub const MOD_M_FRAC2: Field = Field::rw("mod_m_frac2", 0x580D, 15, 0);
    pub const MOD_N2: Field = Field::rw("mod_n2", 0x580F, 3, 2);
    pub const MOD_PS2: Field = Field::rw("mod_ps2", 0x580F, 9, 7);
    /// A different quad order on odd and even frames.
    pub const QUAD_HOP_EN: Field = Field::rw("quad_hop_en", 0x5812, 7, 7);
    /// Resets every register to its default, the TFC and the sensor.
    pub const SOFTWARE_RESET: Field = Field::rw("software_reset", 0x5C00, 0, 0);
    /// Dealiasing across the two PLLs (TI's default profile turns it on).
    pub const DEALIAS_EN: Field = Field::rw("dealias_en", 0x5C02, 23, 23);
    /// Slave address of the illumination temperature sensor.
    pub const TILLUM_SLV_ADDR: Field = Field::rw("tillum_slv_addr", 0x5C2E, 6, 0);
    /// Binning merge factors (1: none), beside `bin_row_count`/`bin_col_count`.
    pub const ROWS_TO_MERGE: Field = Field::rw("rows_to_merge", 0x5C2F, 9, 0);
    pub const COLS_TO_MERGE: Field = Field::rw("cols_to_merge", 0x5C30, 9, 0);
    /// (A - B) scaled down by 2^amplitude_scale in depth output.
    pub const AMPLITUDE_SCALE: Field = Field::rw("amplitude_scale", 0x5C31, 8, 4);
    /// Depth output's saturation flag is set when a well's voltage falls below this.
    pub const SATURATION_THRESHOLD: Field = Field::rw("saturation_threshold", 0x5C36, 23, 12);
    /// Integration shortened by 2^hdr_scale on alternate frames (0: off).
    pub const HDR_SCALE: Field = Field::rw("hdr_scale", 0x5C4C, 8, 6);
    /// Integration shortened by 2^normal_frm_intg_scale (0: off).
    pub const NORMAL_FRM_INTG_SCALE: Field = Field::rw("normal_frm_intg_scale", 0x5C4D, 8, 6);
    pub const FB_READY_EN: Field = Field::rw("fb_ready_en", 0x5C3F, 0, 0);
    pub const OP_CS_POL: Field = Field::rw("op_cs_pol", 0x5C40, 14, 14);
    /// Integration time = intg_duty_cycle / 64 of the quad (easy config).
    pub const INTG_DUTY_CYCLE: Field = Field::rw("intg_duty_cycle", 0x5C4C, 5, 0);
    /// Masked to 0 by the CDK firmware (laser safety).
    pub const LUMPED_DEAD_TIME: Field = Field::rw("lumped_dead_time", 0x5C4C, 22, 22);
    pub const EASY_CONF_EN: Field = Field::rw("easy_conf_en", 0x5C4C, 23, 23);
    /// Temperatures, degrees Celsius, signed 8 bit.
    pub const TSENSOR: Field = Field::ro("tsensor", 0x5C61, 7, 0);
    pub const TILLUM: Field = Field::ro("tillum", 0x5C62, 7, 0);
    // status register 0x5C63
    pub const LVDS_PLL_LOCK: Field = Field::ro("lvds_pll_lock", 0x5C63, 3, 3);
    pub const MASTER_PLL_LOCK: Field = Field::ro("master_pll_lock", 0x5C63, 4, 4);
    /// Output data rate too low (write 0 to reset).
    pub const OP_OVERFLOW: Field = Field::rw("op_overflow", 0x5C63, 20, 20);
    pub const PIX_CNT_MAX_SET_FAILED: Field = Field::ro("pix_cnt_max_set_failed", 0x5C63, 22, 22);
    pub const INTG_DUTY_CYCLE_SET_FAILED: Field =
        Field::ro("intg_duty_cycle_set_failed", 0x5C63, 23, 23);
}

/// Laser-safety limits enforced by the CDK firmware and the SDK; sdid
/// requests within them, reads every write back and reports clamps.
pub mod safety {
    /// intg_duty_cycle at most 20 (of 64): firmware `vendorcommand.c`
    /// `maskTFCRegisters`, SDK `TintinCDKCamera.cpp` `setUpperLimit(20)`.
    pub const INTG_DUTY_CYCLE_MAX: u32 = 20;
    /// pix_cnt_max at least 60000: firmware `maskTFCRegisters` (the SDK's own
    /// lower limit, 50000, is weaker; the firmware's wins).
    pub const PIX_CNT_MAX_MIN: u32 = 60_000;
}

/// Where the OPT8241-CDK's illumination temperature sensor answers (SDK
/// `TintinCDKCamera::_init`, `TILLUM_SLAVE_ADDR`); the chip's default is 0x71.
pub const CDK_TILLUM_SLAVE_ADDRESS: u32 = 0x72;

/// OPT8241 system clock (SDK `ToFTintinCamera::_getSystemClockFrequency`).
pub const SYSTEM_CLOCK_HZ: f64 = 48e6;

#[cfg(test)]
mod tests {
    use super::field::*;
    use super::*;

    #[test]
    fn addresses_split_into_slave_and_register() {
        assert_eq!(PIX_CNT_MAX.slave(), SLAVE_TIMING_GENERATOR);
        assert_eq!(PIX_CNT_MAX.register(), 0x82);
        assert_eq!(INTG_DUTY_CYCLE.slave(), SLAVE_DEPTH_ENGINE);
        assert_eq!(INTG_DUTY_CYCLE.register(), 0x4C);
    }

    #[test]
    fn masks_and_widths() {
        assert_eq!(PIX_CNT_MAX.mask(), 0x3F_FFFF);
        assert_eq!(QUAD_CNT_MAX.mask(), 0x0F);
        assert_eq!(SUB_FRAME_CNT_MAX.mask(), 0xF0);
        assert_eq!(OUTPUT_MODE.mask(), 0xF00);
        assert_eq!(DEBUG_FRAME_NUMBER_EN.mask(), 1 << 12);
        assert_eq!(BLK_SIZE.max(), (1 << 20) - 1);
        assert_eq!(TG_DIS.width_bits(), 1);
    }

    #[test]
    fn read_modify_write_keeps_other_bits() {
        // 0x5883 holds quad_cnt_max [3:0] and sub_frame_cnt_max [7:4].
        let reg = 0x00AB_CD44 & REGISTER_MASK;
        let reg = QUAD_CNT_MAX.insert(reg, 6).unwrap();
        assert_eq!(QUAD_CNT_MAX.extract(reg), 6);
        assert_eq!(SUB_FRAME_CNT_MAX.extract(reg), 4);
        assert_eq!(reg & !0xF, 0x00AB_CD40);
        let reg = OUTPUT_MODE.insert(0xFF_FFFF, 15).unwrap();
        assert_eq!(reg, 0xFF_FFFF);
        let reg = OUTPUT_MODE.insert(0xFF_FFFF, 1).unwrap();
        assert_eq!(reg, 0xFF_F1FF);
    }

    #[test]
    fn oversized_value_is_a_typed_error() {
        let e = QUAD_CNT_MAX.insert(0, 16).unwrap_err();
        assert_eq!(e.max, 15);
        assert!(e.to_string().contains("quad_cnt_max"));
    }

    #[test]
    fn fields_fit_in_24_bits_and_do_not_overlap_within_a_register() {
        let all = [
            TG_DIS,
            PIX_CNT_MAX,
            QUAD_CNT_MAX,
            SUB_FRAME_CNT_MAX,
            MOD_PLL_UPDATE,
            MOD_M_FRAC1,
            MOD_M1,
            MOD_N1,
            MOD_PS1,
            SSCG_EN,
            ILLUM_DC_CORR,
            ILLUM_DC_CORR_DIR,
            ILLUM_P_DIS_POL,
            ILLUM_N_DIS_POL,
            MODULATION_HOLD,
            DEMOD_STATIC_POL,
            ILLUM_STATIC_POL,
            ROW_START,
            ROW_END,
            COL_START,
            COL_END,
            OUTPUT_MODE,
            OP_DATA_ARRANGE_MODE,
            PIXEL_DATA_SIZE,
            BINNING_EN,
            BIN_ROW_COUNT,
            BIN_COL_COUNT,
            OP_CLK_FREQ,
            DEBUG_FRAME_NUMBER_EN,
            BLK_HEADER_EN,
            BLK_SIZE,
            FB_READY_EN,
            OP_CS_POL,
            INTG_DUTY_CYCLE,
            LUMPED_DEAD_TIME,
            EASY_CONF_EN,
            TSENSOR,
            TILLUM,
            LVDS_PLL_LOCK,
            MASTER_PLL_LOCK,
            OP_OVERFLOW,
            PIX_CNT_MAX_SET_FAILED,
            INTG_DUTY_CYCLE_SET_FAILED,
            MOD_M2,
            MOD_M_FRAC2,
            MOD_N2,
            MOD_PS2,
            QUAD_HOP_EN,
            SOFTWARE_RESET,
            DEALIAS_EN,
            TILLUM_SLV_ADDR,
            ROWS_TO_MERGE,
            COLS_TO_MERGE,
            AMPLITUDE_SCALE,
            SATURATION_THRESHOLD,
            HDR_SCALE,
            NORMAL_FRM_INTG_SCALE,
        ];
        for (i, a) in all.iter().enumerate() {
            assert!(a.msb < 24 && a.lsb <= a.msb, "{}", a.name);
            for b in &all[i + 1..] {
                if a.address == b.address {
                    assert_eq!(a.mask() & b.mask(), 0, "{} overlaps {}", a.name, b.name);
                }
            }
        }
    }
}
