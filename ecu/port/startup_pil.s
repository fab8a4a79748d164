/* startup_pil.s - the vector table of the firmware image on the Cortex-M4 (mps2-an386): initial
 * stack pointer, the system exceptions and the board's 32 interrupts. Handlers not defined by
 * the board (board_mps2.c and its CAN link) go to Default_Handler, which stops until the
 * watchdog resets. */
    .syntax unified
    .thumb
    .section .vectors, "a"
    .word __stack_top
    .word Reset_Handler
    .word NMI_Handler
    .word HardFault_Handler
    .rept 7                 /* MemManage, BusFault, UsageFault, 4 reserved */
    .word Default_Handler
    .endr
    .word Default_Handler   /* SVCall */
    .word Default_Handler   /* DebugMonitor */
    .word Default_Handler   /* reserved */
    .word Default_Handler   /* PendSV */
    .word SysTick_Handler
    .word UART0_RX_Handler  /* IRQ 0 */
    .word UART0_TX_Handler  /* IRQ 1 */
    .word UART1_RX_Handler  /* IRQ 2 */
    .word UART1_TX_Handler  /* IRQ 3 */
    .rept 9                 /* IRQ 4..12 */
    .word Default_Handler
    .endr
    .word ETHERNET_Handler  /* IRQ 13 */
    .rept 18                /* IRQ 14..31 */
    .word Default_Handler
    .endr
