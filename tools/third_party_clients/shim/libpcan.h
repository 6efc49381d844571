/* A stand-in for PEAK's libpcan.h, written for barrett-twin: Barrett's BHand API compiles its CAN
 * driver (BH8-280) unconditionally, and that needs the PCAN library, which a serial BH8-262 never
 * uses. Every call fails as if no CAN adapter were present. Names and shapes from what the API's
 * puck2.cpp uses; nothing here is PEAK's code. */
#ifndef BARRETT_TWIN_LIBPCAN_SHIM_H
#define BARRETT_TWIN_LIBPCAN_SHIM_H

#include <stdint.h>

typedef void *HANDLE;
typedef uint32_t DWORD;
typedef uint16_t WORD;
typedef uint8_t BYTE;

typedef struct {
    DWORD ID;
    BYTE MSGTYPE;
    BYTE LEN;
    BYTE DATA[8];
} TPCANMsg;

typedef struct {
    TPCANMsg Msg;
    DWORD dwTime;
    WORD wUsec;
} TPCANRdMsg;

#define MSGTYPE_STANDARD 0x00
#define CAN_BAUD_1M 0x0014
#define CAN_INIT_TYPE_ST 0x01
#define CAN_ERR_OK 0x0000
#define CAN_ERR_BUSOFF 0x0010
#define CAN_ERR_NO_ADAPTER 0x4000 /* what every call below answers */

static inline HANDLE LINUX_CAN_Open(const char *node, int mode) { (void)node; (void)mode; return 0; }
static inline DWORD CAN_Init(HANDLE h, WORD baud, int type) { (void)h; (void)baud; (void)type; return CAN_ERR_NO_ADAPTER; }
static inline DWORD CAN_Close(HANDLE h) { (void)h; return CAN_ERR_OK; }
static inline DWORD CAN_Status(HANDLE h) { (void)h; return CAN_ERR_NO_ADAPTER; }
static inline DWORD CAN_Write(HANDLE h, TPCANMsg *m) { (void)h; (void)m; return CAN_ERR_NO_ADAPTER; }
static inline DWORD CAN_Read(HANDLE h, TPCANMsg *m) { (void)h; (void)m; return CAN_ERR_NO_ADAPTER; }
static inline DWORD LINUX_CAN_Read(HANDLE h, TPCANRdMsg *m) { (void)h; (void)m; return CAN_ERR_NO_ADAPTER; }
static inline DWORD LINUX_CAN_Read_Timeout(HANDLE h, TPCANRdMsg *m, int us) { (void)h; (void)m; (void)us; return CAN_ERR_NO_ADAPTER; }
static inline DWORD CAN_MsgFilter(HANDLE h, DWORD from, DWORD to, int type) { (void)h; (void)from; (void)to; (void)type; return CAN_ERR_NO_ADAPTER; }
static inline DWORD CAN_ResetClient(HANDLE h) { (void)h; return CAN_ERR_NO_ADAPTER; }

#endif
